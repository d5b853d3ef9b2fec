"""The server's state as Foxglove messages (foxglove.* protobuf schemas), each encoded once to
bytes that the live server and a recording both log. They run in the telemetry process
(:mod:`.worker`): the server's hub sends a function here and its arguments, plain values and
arrays, since the SDK's encoding holds the GIL while it copies (a map layer's Grid for several
milliseconds).

Frames (docs/PROTOCOL.md, Foxglove): ``world`` (the global frame: x, y as the pose, z up) ->
``rover`` (the believed pose) -> ``mast`` (the pan axis' foot, ``head.ptu_base``) -> ``ptu_pan``
-> ``ptu_tilt`` -> one optical frame per mounted sensor (``tof``, ``stereo_left``,
``stereo_right``, any other mount by its name: x right, y down, z forward, as Foxglove's
cameras and the drivers' images). The body's own cameras hang from ``rover``: each hazard
camera pair's ``hazcam_<pair>_left`` and ``hazcam_<pair>_right``, optical frames as above.
``world`` -> ``rover_truth`` is the simulated rover.
"""

from __future__ import annotations

import json
from typing import Any

import cv2
import numpy as np
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CompressedImage,
    CubePrimitive,
    FrameTransform,
    FrameTransforms,
    Grid,
    LinePrimitive,
    LinePrimitiveLineType,
    Log,
    LogLevel,
    PackedElementField,
    PackedElementFieldNumericType,
    Point3,
    PointCloud,
    Pose,
    PoseInFrame,
    Quaternion,
    RawImage,
    SceneEntity,
    SceneUpdate,
    TextPrimitive,
    Timestamp,
    Vector2,
    Vector3,
)

from prox_workflows.algorithms.transforms import HeadCalibration, T_global_from_rover, make_T, rot_y, rot_z
from prox_workflows.grid import GridGeometry
from rvs_params.deferred import deferred

transform = deferred("scipy.spatial.transform")

WORLD = "world"
SENSOR_FRAMES = {"left": "stereo_left", "right": "stereo_right"}  # mount name -> frame id (else the name)

_NUMERIC = {
    np.dtype(np.uint8): PackedElementFieldNumericType.Uint8,
    np.dtype(np.int8): PackedElementFieldNumericType.Int8,
    np.dtype(np.uint16): PackedElementFieldNumericType.Uint16,
    np.dtype(np.int16): PackedElementFieldNumericType.Int16,
    np.dtype(np.uint32): PackedElementFieldNumericType.Uint32,
    np.dtype(np.int32): PackedElementFieldNumericType.Int32,
    np.dtype(np.float32): PackedElementFieldNumericType.Float32,
    np.dtype(np.float64): PackedElementFieldNumericType.Float64,
}
DTYPES = {int(v): k for k, v in _NUMERIC.items()}  # a Grid field's numeric type -> the layer's dtype

PLAN_COLOUR = Color(r=1.0, g=0.55, b=0.0, a=1.0)
TRACK_COLOUR = Color(r=0.1, g=0.5, b=1.0, a=1.0)
VERDICT_COLOUR = {"safe": Color(r=0.1, g=0.8, b=0.2, a=0.8), "blocked": Color(r=0.9, g=0.1, b=0.1, a=0.8)}
UNKNOWN_COLOUR = Color(r=0.6, g=0.6, b=0.6, a=0.8)


def stamp(t_ns: int) -> Timestamp:
    return Timestamp(t_ns // 1_000_000_000, t_ns % 1_000_000_000)


def sensor_frame(mount: str) -> str:
    return SENSOR_FRAMES.get(mount, mount)


def hazcam_frame(pair: str, side: str) -> str:
    """The optical frame of one camera (``left``, ``right``) of a body hazard camera pair."""
    return f"hazcam_{pair}_{side}"


def _pose(T: np.ndarray) -> Pose:
    return Pose(position=_vector(T[:3, 3]), orientation=_quaternion(T[:3, :3]))


def _vector(t: Any) -> Vector3:
    return Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2]))


def _quaternion(R: np.ndarray) -> Quaternion:
    x, y, z, w = transform.Rotation.from_matrix(R).as_quat()
    return Quaternion(x=float(x), y=float(y), z=float(z), w=float(w))


def _transform(t_ns: int, parent: str, child: str, T: np.ndarray) -> FrameTransform:
    return FrameTransform(timestamp=stamp(t_ns), parent_frame_id=parent, child_frame_id=child,
                          translation=_vector(T[:3, 3]), rotation=_quaternion(T[:3, :3]))


def frame_transforms(head: HeadCalibration, pose: tuple[float, ...], ptu: tuple[float, float] | None,
                     truth: tuple[float, ...] | None,
                     body: list[tuple[str, np.ndarray]] | tuple[()] = ()) -> list[tuple[str, str, np.ndarray]]:
    """The whole tree as (parent, child, 4 x 4 pose of the child in the parent): pose (x, y,
    heading, ground z, roll, pitch), PTU (pan, tilt; 0, 0 unknown), the simulated rover's true
    (x, y, heading, roll, pitch) on the same ground height; ``body``: the frames fixed on the
    rover (frame id, its 4 x 4 pose in the rover frame)."""
    pan, tilt = ptu or (0.0, 0.0)
    tree = [
        (WORLD, "rover", T_global_from_rover(*pose)),
        ("rover", "mast", make_T(None, head.ptu_base)),
        ("mast", "ptu_pan", make_T(rot_z(pan))),
        ("ptu_pan", "ptu_tilt", make_T(rot_y(-tilt), (0.0, 0.0, head.tilt_offset))),
    ]
    tree += [("ptu_tilt", sensor_frame(name), head.T_tilt_from_sensor(name)) for name in head.mounts]
    tree += [("rover", frame, T) for frame, T in body]
    if truth is not None:
        tree.append((WORLD, "rover_truth", T_global_from_rover(*truth[:3], pose[3], *truth[3:])))
    return tree


def frame_tree(t_ns: int, head: HeadCalibration, pose: tuple[float, ...],
               ptu: tuple[float, float] | None, truth: tuple[float, ...] | None,
               body: list[tuple[str, np.ndarray]] | tuple[()] = ()) -> bytes:
    """The whole tree at ``t_ns`` (:func:`frame_transforms`)."""
    return FrameTransforms(transforms=[_transform(t_ns, parent, child, T) for parent, child, T
                                       in frame_transforms(head, pose, ptu, truth, body)]).encode()


def pose_in_world(t_ns: int, x: float, y: float, heading: float, z: float, roll: float = 0.0,
                  pitch: float = 0.0) -> bytes:
    return PoseInFrame(timestamp=stamp(t_ns), frame_id=WORLD,
                       pose=_pose(T_global_from_rover(x, y, heading, z, roll, pitch))).encode()


def grid(t_ns: int, g: GridGeometry, layers: dict[str, np.ndarray]) -> bytes:
    """Layers of one grid as a Grid in ``world``, a field per layer named after it (in the layers'
    type when they share one, else float32). Foxglove's cells run from the origin corner along
    +x then +y, ours north-up from the north-west corner, so the rows are sent south first and
    the origin is the south-west corner (xmin, ymin)."""
    dtypes = {v.dtype for v in layers.values()}
    dtype = dtypes.pop() if len(dtypes) == 1 else np.dtype(np.float32)
    if dtype not in _NUMERIC:
        dtype = np.dtype(np.float32)
    cells = np.ascontiguousarray(np.stack([np.flipud(v).astype(dtype, copy=False) for v in layers.values()], axis=-1))
    size = dtype.itemsize * len(layers)
    fields = [PackedElementField(name=name, offset=i * dtype.itemsize, type=_NUMERIC[dtype])
              for i, name in enumerate(layers)]
    return Grid(timestamp=stamp(t_ns), frame_id=WORLD, pose=_pose(make_T(None, (g.xmin, g.ymin, 0.0))),
                column_count=g.width, cell_size=Vector2(x=g.cell, y=g.cell), row_stride=g.width * size,
                cell_stride=size, fields=fields, data=cells.tobytes()).encode()


def cloud(t_ns: int, frame: str, xyz: np.ndarray, values: np.ndarray, name: str) -> bytes:
    """Points (N x 3) in ``frame`` with one value each: fields x, y, z and ``name``, float32."""
    packed = np.empty((len(xyz), 4), np.float32)
    packed[:, :3] = xyz
    packed[:, 3] = values
    fields = [PackedElementField(name=n, offset=4 * i, type=PackedElementFieldNumericType.Float32)
              for i, n in enumerate(("x", "y", "z", name))]
    return PointCloud(timestamp=stamp(t_ns), frame_id=frame, pose=_pose(np.eye(4)), point_stride=16,
                      fields=fields, data=packed.tobytes()).encode()


def defined_points(xyz: np.ndarray, amplitude: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The defined points of an organised H x W x 3 image (the ToF's: -1 where undefined) and
    their amplitude."""
    valid = xyz[..., 2] > 0
    return xyz[valid], amplitude[valid]


def point_cloud(t_ns: int, frame: str, xyz: np.ndarray, amplitude: np.ndarray) -> bytes:
    """The defined points of an organised point image with their amplitude, in the sensor's frame."""
    return cloud(t_ns, frame, *defined_points(xyz, amplitude), "intensity")


def depth_image(xyz: np.ndarray) -> np.ndarray:
    """An organised point image's z as a depth image, NaN where undefined."""
    return np.where(xyz[..., 2] > 0, xyz[..., 2], np.nan).astype(np.float32)


def depth(t_ns: int, frame: str, xyz: np.ndarray) -> bytes:
    return raw_image(t_ns, frame, depth_image(xyz))


def image_encoding(image: np.ndarray) -> tuple[np.ndarray, str]:
    """An image as the driver returned it, contiguous, and its encoding's name (ROS's, which
    Foxglove's RawImage shares): float32 (1 or 3 channels, NaN or -1 undefined), 16-bit, else
    mono8 or rgb8."""
    image = np.ascontiguousarray(image)
    channels = 1 if image.ndim == 2 else image.shape[2]
    if image.dtype == np.float32:
        return image, f"32FC{channels}"
    if image.dtype == np.uint16:
        return image, "mono16" if channels == 1 else "rgb16"
    return image.astype(np.uint8, copy=False), "mono8" if channels == 1 else "rgb8"


def raw_image(t_ns: int, frame: str, image: np.ndarray) -> bytes:
    """An image as the driver returned it, full resolution (:func:`image_encoding`)."""
    image, encoding = image_encoding(image)
    return RawImage(timestamp=stamp(t_ns), frame_id=frame, width=image.shape[1], height=image.shape[0],
                    encoding=encoding, step=image.strides[0], data=image.tobytes()).encode()


def jpeg_bytes(image: np.ndarray, quality: int = 85) -> bytes:
    """A camera image JPEG-compressed (what a live view needs: a tenth of the bytes)."""
    if image.dtype != np.uint8:
        image = (image >> 8).astype(np.uint8) if image.dtype == np.uint16 else np.clip(image, 0, 255).astype(np.uint8)
    if image.ndim == 3:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("the image could not be JPEG-encoded")
    return data.tobytes()


def jpeg(t_ns: int, frame: str, image: np.ndarray) -> bytes:
    return CompressedImage(timestamp=stamp(t_ns), frame_id=frame, data=jpeg_bytes(image), format="jpeg").encode()


def _line(points: list[tuple[float, float, float]] | list[list[float]], colour: Color, thickness: float) -> LinePrimitive:
    return LinePrimitive(type=LinePrimitiveLineType.LineStrip, pose=_pose(np.eye(4)), thickness=thickness,
                         scale_invariant=True, points=[Point3(x=x, y=y, z=z) for x, y, z in points], color=colour)


def _text(x: float, y: float, z: float, text: str) -> TextPrimitive:
    return TextPrimitive(pose=_pose(make_T(None, (x, y, z))), billboard=True, font_size=14.0, scale_invariant=True,
                         color=Color(r=1.0, g=1.0, b=1.0, a=1.0), text=text)


def plan(t_ns: int, waypoints: list[tuple[float, float, float]], z: float, leg: Any) -> bytes:
    """A leg's plan: the line through its waypoints and an arrow per waypoint along its heading."""
    arrows = [ArrowPrimitive(pose=_pose(T_global_from_rover(x, y, h, z + 0.05)), shaft_length=0.25, shaft_diameter=0.04,
                             head_length=0.1, head_diameter=0.1, color=PLAN_COLOUR) for x, y, h in waypoints]
    entity = SceneEntity(timestamp=stamp(t_ns), frame_id=WORLD, id="plan", arrows=arrows,
                         lines=[_line([(x, y, z + 0.05) for x, y, _ in waypoints], PLAN_COLOUR, 3.0)],
                         texts=[_text(*waypoints[-1][:2], z + 0.4, f"leg {leg}")] if waypoints else [])
    return SceneUpdate(entities=[entity]).encode()


def track(t_ns: int, points: np.ndarray) -> bytes:
    """The driven track, n x 3 (the simulated rover's true positions where there is one)."""
    entity = SceneEntity(timestamp=stamp(t_ns), frame_id=WORLD, id="track",
                         lines=[_line(np.asarray(points, float).tolist(), TRACK_COLOUR, 2.0)])
    return SceneUpdate(entities=[entity]).encode()


def check_move(t_ns: int, start: tuple[float, float, float], fields: dict[str, Any], z: float,
               footprint: tuple[float, float]) -> bytes:
    """A check-move's answer: the move as a line, the rover's box at its end coloured by the
    verdict, the worst cell marked, and the verdict as text."""
    end = [float(v) for v in fields["to"]]
    verdict = str(fields.get("verdict"))
    colour = VERDICT_COLOUR.get(verdict, UNKNOWN_COLOUR)
    box = CubePrimitive(pose=_pose(T_global_from_rover(end[0], end[1], end[2], z + 0.1)),
                        size=Vector3(x=footprint[0], y=footprint[1], z=0.2), color=colour)
    cubes = [box]
    if verdict != "safe" and "worst_x" in fields:
        cubes.append(CubePrimitive(pose=_pose(make_T(None, (float(fields["worst_x"]), float(fields["worst_y"]), z))),
                                   size=Vector3(x=0.1, y=0.1, z=0.3), color=colour))
    entity = SceneEntity(timestamp=stamp(t_ns), frame_id=WORLD, id="check_move", cubes=cubes,
                         lines=[_line([(start[0], start[1], z + 0.05), (end[0], end[1], z + 0.05)], colour, 2.0)],
                         texts=[_text(end[0], end[1], z + 0.5, f"check-move: {verdict}")])
    return SceneUpdate(entities=[entity]).encode()


_LEVEL = {"ERROR": LogLevel.Error, "EVENT": LogLevel.Info}


def log_level_name(direction: str, conn: Any, status: str = "", kind: str = "") -> tuple[LogLevel, str]:
    """A wire line's level and who sent it which way (``conn 3 >`` a request, ``conn 3 <`` a
    reply, ``event`` an EVENT): ERROR lines (``status``) are errors, hazard and fault events
    (an EVENT's ``kind``) warnings."""
    level = _LEVEL.get(status, LogLevel.Info)
    if status == "EVENT" and kind.startswith(("hazard", "fault")):
        level = LogLevel.Warning
    return level, "event" if direction == "event" else f"conn {conn} {'>' if direction == 'request' else '<'}"


def log_line(t_ns: int, direction: str, conn: Any, text: str, status: str = "", kind: str = "") -> bytes:
    """A wire line as a Log (:func:`log_level_name`)."""
    level, name = log_level_name(direction, conn, status, kind)
    return Log(timestamp=stamp(t_ns), level=level, message=text, name=name).encode()


def json_bytes(obj: dict[str, Any]) -> bytes:
    return json.dumps(obj, separators=(",", ":"), default=str).encode()
