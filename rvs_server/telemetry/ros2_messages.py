"""The messages of :mod:`.messages` as ROS 2 messages, for a recording of the ``ros2`` profile:
each function here takes the arguments of its Foxglove counterpart, so the hub's one feed
drives both and only the encoding differs (:data:`ENCODERS`). Frame ids, topics and times are
the same; the types (definitions in :mod:`.ros2_msgs`):

- the frame tree: ``tf2_msgs/msg/TFMessage``; poses: ``geometry_msgs/msg/PoseStamped``;
- clouds: ``sensor_msgs/msg/PointCloud2`` (unorganised, float32 fields);
- images: ``sensor_msgs/msg/Image``, JPEGs ``sensor_msgs/msg/CompressedImage``;
- map layers and the bounds map: ``grid_map_msgs/msg/GridMap``;
- the plan and the track: ``nav_msgs/msg/Path``;
- wire lines: ``rcl_interfaces/msg/Log``;
- what Foxglove gets as JSON (job progress, the wire's copy, device calls) and the check-move's
  answer (a Foxglove scene, which ROS 2 has no stable plain type for): ``std_msgs/msg/String``
  holding the JSON.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from typing import Any

import numpy as np
from foxglove.messages import LogLevel
from mcap_ros2._cdr import CdrWriter  # the generic encoder's own writer (the version is pinned: pyproject)

from prox_workflows.algorithms.transforms import T_global_from_rover
from prox_workflows.grid import GridGeometry
from rvs_params.deferred import deferred

from . import messages as m
from .ros2_msgs import encoder, type_name

transform = deferred("scipy.spatial.transform")

# ROS 2's Log levels (rcl_interfaces/msg/Log's constants) by Foxglove's level's value
ROS_LEVEL = {level.value: ros for level, ros in ((LogLevel.Debug, 10), (LogLevel.Info, 20), (LogLevel.Warning, 30),
                                                 (LogLevel.Error, 40), (LogLevel.Fatal, 50))}
FLOAT32 = 7  # sensor_msgs/msg/PointField.FLOAT32

# a function of .messages -> (the ROS 2 type it becomes, as pkg/Type; the function that encodes it)
ENCODERS: dict[Callable[..., bytes], tuple[str, Callable[..., bytes]]] = {}


Build = Callable[..., dict[str, Any]]


def encodes(foxglove: Callable[..., bytes], short: str,
            cdr: Callable[[dict[str, Any]], bytes] | None = None) -> Callable[[Build], Build]:
    """Register the decorated function (the arguments of ``foxglove``, the message as dicts) as
    the ROS 2 form of ``foxglove``'s message, of type ``short``; it stays the dicts' builder.
    ``cdr``: the message's own encoder, where the generic one is too slow."""
    def register(build: Build) -> Build:
        encode = cdr or encoder(short)

        def ros2(*args: Any) -> bytes:
            return encode(build(*args))

        ENCODERS[foxglove] = (short, ros2)
        return build
    return register


def ros2_type(foxglove: Callable[..., bytes]) -> str:
    """The schema name (``pkg/msg/Type``) of ``foxglove``'s message in a ROS 2 recording."""
    return type_name(ENCODERS[foxglove][0])


def header(t_ns: int, frame: str) -> dict[str, Any]:
    return {"stamp": {"sec": t_ns // 1_000_000_000, "nanosec": t_ns % 1_000_000_000}, "frame_id": frame}


def _xyz(t: Any) -> dict[str, float]:
    return {"x": float(t[0]), "y": float(t[1]), "z": float(t[2])}


def _quaternion(R: np.ndarray) -> dict[str, float]:
    x, y, z, w = transform.Rotation.from_matrix(R).as_quat()
    return {"x": float(x), "y": float(y), "z": float(z), "w": float(w)}


def _pose(T: np.ndarray) -> dict[str, Any]:
    return {"position": _xyz(T[:3, 3]), "orientation": _quaternion(T[:3, :3])}


@encodes(m.frame_tree, "tf2_msgs/TFMessage")
def frame_tree(t_ns: int, *tree: Any) -> dict[str, Any]:
    return {"transforms": [{"header": header(t_ns, parent), "child_frame_id": child,
                            "transform": {"translation": _xyz(T[:3, 3]), "rotation": _quaternion(T[:3, :3])}}
                           for parent, child, T in m.frame_transforms(*tree)]}


@encodes(m.pose_in_world, "geometry_msgs/PoseStamped")
def pose_in_world(t_ns: int, x: float, y: float, heading: float, z: float, roll: float = 0.0,
                  pitch: float = 0.0) -> dict[str, Any]:
    return {"header": header(t_ns, m.WORLD), "pose": _pose(T_global_from_rover(x, y, heading, z, roll, pitch))}


def grid_map_cdr(msg: dict[str, Any]) -> bytes:
    """A GridMap's CDR bytes, each layer's float32 cells written as one block: the generic encoder
    writes a float32[] one number at a time (about 3 us each: 31 s for ten 1717 x 1717 layers).
    The same bytes as the generic encoder's (tests/server/telemetry/test_ros2_record.py)."""
    out = io.BytesIO()
    w = CdrWriter(out)
    h = msg["header"]
    w.write_int32(h["stamp"]["sec"])
    w.write_uint32(h["stamp"]["nanosec"])
    w.write_string(h["frame_id"])
    info = msg["info"]
    for value in (info["resolution"], info["length_x"], info["length_y"], *info["pose"]["position"].values(),
                  *info["pose"]["orientation"].values()):
        w.write_float64(value)
    for names in (msg["layers"], msg["basic_layers"]):
        w.write_uint32(len(names))
        for name in names:
            w.write_string(name)
    w.write_uint32(len(msg["data"]))
    for layer in msg["data"]:
        w.write_uint32(len(layer["layout"]["dim"]))
        for dim in layer["layout"]["dim"]:
            w.write_string(dim["label"])
            w.write_uint32(dim["size"])
            w.write_uint32(dim["stride"])
        w.write_uint32(layer["layout"]["data_offset"])
        cells = np.ascontiguousarray(layer["data"], dtype="<f4")
        w.write_uint32(cells.size)
        w.write_bytes(cells.tobytes())  # after a uint32, so already 4-byte aligned
    w.write_uint16(msg.get("outer_start_index", 0))
    w.write_uint16(msg.get("inner_start_index", 0))
    return out.getvalue()


@encodes(m.grid, "grid_map_msgs/GridMap", grid_map_cdr)
def grid(t_ns: int, g: GridGeometry, layers: dict[str, np.ndarray]) -> dict[str, Any]:
    """Layers of one grid, float32 (NaN: no value, as grid_map has it), centred on the grid's
    centre in ``world``. grid_map's cell (0, 0) is the corner at the largest x and y, its rows
    run along -x and its columns along -y, stored column-major: for our north-up layer (rows
    north first, columns west first) that is each row reversed, row after row."""
    width, height = g.width * g.cell, g.height * g.cell
    centre = m.make_T(None, (g.xmin + width / 2, g.ymin + height / 2, 0.0))
    layout = {"dim": [{"label": "column_index", "size": g.height, "stride": g.width * g.height},
                      {"label": "row_index", "size": g.width, "stride": g.width}], "data_offset": 0}
    return {"header": header(t_ns, m.WORLD),
            "info": {"resolution": g.cell, "length_x": width, "length_y": height, "pose": _pose(centre)},
            "layers": list(layers), "basic_layers": [],
            "data": [{"layout": layout, "data": np.asarray(v, np.float32)[:, ::-1].ravel()}
                     for v in layers.values()]}


@encodes(m.cloud, "sensor_msgs/PointCloud2")
def cloud(t_ns: int, frame: str, xyz: np.ndarray, values: np.ndarray, name: str) -> dict[str, Any]:
    """Points (N x 3) with one value each: fields x, y, z and ``name``, float32, one row."""
    packed = np.empty((len(xyz), 4), np.float32)
    packed[:, :3] = xyz
    packed[:, 3] = values
    fields = [{"name": n, "offset": 4 * i, "datatype": FLOAT32, "count": 1} for i, n in enumerate(("x", "y", "z", name))]
    return {"header": header(t_ns, frame), "height": 1, "width": len(packed), "fields": fields,
            "is_bigendian": False, "point_step": 16, "row_step": 16 * len(packed), "data": packed.tobytes(),
            "is_dense": bool(np.isfinite(packed).all())}


@encodes(m.point_cloud, "sensor_msgs/PointCloud2")
def point_cloud(t_ns: int, frame: str, xyz: np.ndarray, amplitude: np.ndarray) -> dict[str, Any]:
    return cloud(t_ns, frame, *m.defined_points(xyz, amplitude), "intensity")


@encodes(m.raw_image, "sensor_msgs/Image")
def raw_image(t_ns: int, frame: str, image: np.ndarray) -> dict[str, Any]:
    image, encoding = m.image_encoding(image)
    return {"header": header(t_ns, frame), "height": image.shape[0], "width": image.shape[1], "encoding": encoding,
            "is_bigendian": 0, "step": image.strides[0], "data": image.tobytes()}


@encodes(m.depth, "sensor_msgs/Image")
def depth(t_ns: int, frame: str, xyz: np.ndarray) -> dict[str, Any]:
    return raw_image(t_ns, frame, m.depth_image(xyz))


@encodes(m.jpeg, "sensor_msgs/CompressedImage")
def jpeg(t_ns: int, frame: str, image: np.ndarray) -> dict[str, Any]:
    return {"header": header(t_ns, frame), "format": "jpeg", "data": m.jpeg_bytes(image)}


def _path(t_ns: int, poses: list[np.ndarray]) -> dict[str, Any]:
    return {"header": header(t_ns, m.WORLD), "poses": [{"header": header(t_ns, m.WORLD), "pose": _pose(T)}
                                                       for T in poses]}


@encodes(m.plan, "nav_msgs/Path")
def plan(t_ns: int, waypoints: list[tuple[float, float, float]], z: float, leg: Any) -> dict[str, Any]:
    """A leg's waypoints with their headings, on the ground."""
    return _path(t_ns, [T_global_from_rover(x, y, h, z) for x, y, h in waypoints])


@encodes(m.track, "nav_msgs/Path")
def track(t_ns: int, points: np.ndarray) -> dict[str, Any]:
    return _path(t_ns, [m.make_T(None, p) for p in np.asarray(points, float)])


@encodes(m.check_move, "std_msgs/String")
def check_move(t_ns: int, start: tuple[float, float, float], fields: dict[str, Any], z: float,
               footprint: tuple[float, float]) -> dict[str, Any]:
    """The check-move's reply fields and where the move started (x, y, heading), as JSON."""
    return {"data": m.json_bytes({"from": list(start), **fields}).decode()}


@encodes(m.log_line, "rcl_interfaces/Log")
def log_line(t_ns: int, direction: str, conn: Any, text: str, status: str = "", kind: str = "") -> dict[str, Any]:
    level, name = m.log_level_name(direction, conn, status, kind)
    return {"stamp": header(t_ns, "")["stamp"], "level": ROS_LEVEL[level.value], "name": name, "msg": text}


@encodes(m.json_bytes, "std_msgs/String")
def json_text(obj: dict[str, Any]) -> dict[str, Any]:
    return {"data": m.json_bytes(obj).decode()}
