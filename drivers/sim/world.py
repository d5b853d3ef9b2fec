"""The simulated world every simulated device sees: terrain, objects, rover, sensor head.

One ``World`` is shared by the PTU emulator (which moves the head), the ToF and stereo
simulators (which render from the head) and the trigger (which wakes the cameras). State that
moves (PTU angles, rover pose, target time, checkerboard) sits behind one lock; ``render``
copies a consistent snapshot under the lock and ray casts outside it.
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.sim.albedo import load_texture
from drivers.sim.clock import ScaleSource, SimClock
from drivers.sim.head import HeadGeometry
from drivers.sim.heightfield import Heightfield
from drivers.sim.noise import periodic_tile
from drivers.sim.objects import Rect, SceneObject, checker_albedo
from drivers.sim.render import Detail, Render, render
from drivers.sim.rover import RoverBody, RoverDrive, Slip, resting_pose, step_pose
from drivers.sim.scene import (
    CHECKERBOARD_ID,
    FIRST_OBJECT_ID,
    build_object,
    build_rover,
    build_target,
    load_scene_spec,
)
from drivers.sim.settings import AlbedoSettings, OpticsSettings, SceneLook, SunSettings
from drivers.sim.shadows import sunlit_map
from drivers.sim.terrain import add_rock, build_terrain, data_file
from drivers.sim.trajectory import Trajectory
from drivers.sim.transforms import invert, make_T, rot_z, rover_rotation, transform
from drivers.sim.trigger import TriggerBus

__all__ = ["World", "Render", "CameraTruth", "HeadGeometry"]


@dataclass
class CameraTruth:
    """The true calibration of one sensor, to test calibration code against.

    ``K``: intrinsics; ``dist``: OpenCV distortion (zero: the renderer is an ideal pinhole);
    ``T_world_cam``: current pose; ``T_tilt_cam``: the mount on the PTU's tilt frame (the
    hand-eye transform); ``T_rover_cam``: camera in the rover frame at the current PTU angles.
    """

    K: np.ndarray
    dist: np.ndarray
    T_world_cam: np.ndarray
    T_tilt_cam: np.ndarray
    T_rover_cam: np.ndarray


class World:
    """``clock_scale``: the simulated clock's speed-up (simulated seconds per wall second, 0
    instant; a callable is read each time, so the server's ``sim.time_scale`` applies live)."""

    def __init__(self, spec: dict, seed: int | None = None, clock_scale: ScaleSource = 1.0) -> None:
        self._lock = threading.RLock()
        self.trigger = TriggerBus()
        # One clock for everything that takes time in the simulated world (drive, PTU, ToF
        # frames); it outlives scene changes, as time does.
        self.clock = SimClock(clock_scale)
        self._drive_lock = threading.Lock()  # one drive at a time (navigate -auto or sim drive)
        self._rock_lock = threading.Lock()  # one rock added at a time (add_rock)
        # the rover's resting pose, held for the (pose, body, terrain) it was found on: rover_rest
        self._rest: tuple[tuple, tuple[float, float, float]] | None = None
        self._under_way = 0  # a drive loop keeps the rover rolling between its drive calls
        self._pan = 0.0
        self._tilt = 0.0
        # who is told where the PTU is heading when a move starts (a simulated camera renders
        # the view there meanwhile, as a real one costs no rendering at all)
        self._ptu_watchers: list[Callable[[float, float], None]] = []
        self._load(spec, seed)

    # -- construction ---------------------------------------------------------------------
    @classmethod
    def from_scene(cls, name_or_path: str | Path, seed: int | None = None,
                   clock_scale: ScaleSource = 1.0) -> World:
        """Build from ``config/scenes/<name>.yaml`` (or a path); ``seed`` overrides the file's."""
        return cls(load_scene_spec(name_or_path), seed, clock_scale)

    def load_scene(self, name_or_path: str | Path, seed: int | None = None) -> None:
        """Swap in another scene in place (devices keep their reference to this world); the
        PTU angles and the trigger count carry over, the rover goes to the scene's start."""
        spec = load_scene_spec(name_or_path)
        with self._lock:
            self._load(spec, seed)

    def _load(self, spec: dict, seed: int | None) -> None:
        seed = int(spec.get("seed", 0) if seed is None else seed)
        look = SceneLook.from_spec(spec)
        terrain, z0, tile = _ground(spec, seed, look)
        detail = Detail(tile, **spec.get("detail", {}))
        head = HeadGeometry.from_spec(spec.get("head"))
        objects = [build_object(o, FIRST_OBJECT_ID + i) for i, o in enumerate(spec.get("objects", []))]
        rover_spec = spec.get("rover", {})
        rover = build_rover(rover_spec, head)
        drive = RoverDrive.from_spec(rover_spec)
        slip_spec = rover_spec.get("slip") or {}
        slip = Slip(float(slip_spec.get("distance", 0.0)), float(slip_spec.get("heading", 0.0)),
                    int(slip_spec.get("seed", seed)))
        target = build_target(spec["target"]) if spec.get("target") else None
        traj = None
        if target is not None:
            traj = Trajectory.from_spec(spec["target"].get("waypoints", [[0.0, 3.0, 0.0]]),
                                        bool(spec["target"].get("loop", False)))
        with self._lock:
            self.spec = spec
            # the scene's sun (shading and shadows), albedo source and camera optics, typed
            self.sun: SunSettings = look.sun
            self.albedo_source: AlbedoSettings = look.albedo
            self.optics: OpticsSettings = look.optics
            self.scene_name = str(spec.get("name"))
            self.seed = seed
            self.terrain: Heightfield = terrain
            self.z_shift = float(z0)  # subtracted from the scene's heights (the rover's origin at its start at 0)
            self.detail = detail
            self.head = head
            self._objects = objects
            self._rover_obj = rover
            self._target_obj = target
            self._trajectory = traj
            self._target_time = 0.0
            self._board: SceneObject | None = None
            self._board_geom: tuple[np.ndarray, int, int, float] | None = None
            start = rover_spec.get("start", {})
            self._rover = (float(start.get("x", 0.0)), float(start.get("y", 0.0)),
                           float(start.get("heading", 0.0)))
            # The rover's dead-reckoned pose (wheel odometry): equal to the truth until slip
            # or drift pulls them apart while driving.
            self._odom = self._rover
            self.drive_model = drive
            self.body = RoverBody.from_spec(rover_spec.get("body"))  # what the rover drives over
            self.slip = slip
            self._rock_rng = np.random.default_rng([seed, 7])  # rocks added at run time
            cb = spec.get("checkerboard")
            if cb:
                from drivers.sim.transforms import pose_from_spec

                self.place_checkerboard(pose_from_spec(cb.get("pose")), int(cb.get("rows", 7)),
                                        int(cb.get("cols", 9)), float(cb.get("square", 0.05)))

    def rocks(self) -> list[dict[str, float]]:
        """Every rock the terrain holds: centre x, y, half-axes a, b, yaw and the height it
        stands above the ground around it (ground truth for hazard detection)."""
        return [dict(r) for r in self.terrain.rocks]

    @property
    def object_ids(self) -> dict[str, int]:
        """Names of everything the renderer can hit, to decode ``Render.object_id``."""
        with self._lock:
            ids = {"terrain": 0, "rover": self._rover_obj.oid}
            if self._target_obj is not None:
                ids["target"] = self._target_obj.oid
            if self._board is not None:
                ids["checkerboard"] = self._board.oid
            ids.update({o.name: o.oid for o in self._objects})
            return ids

    # -- PTU and rover ----------------------------------------------------------------------
    def set_ptu(self, pan_deg: float, tilt_deg: float) -> None:
        with self._lock:
            self._pan, self._tilt = float(pan_deg), float(tilt_deg)

    def ptu(self) -> tuple[float, float]:
        with self._lock:
            return self._pan, self._tilt

    def watch_ptu_target(self, fn: Callable[[float, float], None]) -> None:
        """Call ``fn(pan, tilt)`` (degrees, where the PTU will stop) whenever a move starts."""
        with self._lock:
            self._ptu_watchers.append(fn)

    def unwatch_ptu_target(self, fn: Callable[[float, float], None]) -> None:
        with self._lock:
            self._ptu_watchers = [w for w in self._ptu_watchers if w != fn]

    def set_ptu_target(self, pan_deg: float, tilt_deg: float) -> None:
        """The PTU started toward (pan, tilt): the simulated PTU says so as its move starts."""
        with self._lock:
            watchers = list(self._ptu_watchers)
        for fn in watchers:
            fn(float(pan_deg), float(tilt_deg))

    def sensor_pose_at(self, sensor: str, pan_deg: float, tilt_deg: float) -> np.ndarray:
        """T_world_from_camera of ``sensor`` with the PTU at (pan, tilt) and the rover where it is."""
        with self._lock:
            return self.T_world_rover() @ self.head.T_rover_from_sensor(sensor, pan_deg, tilt_deg)

    def rover_pose(self) -> tuple[float, float, float]:
        """x, y, heading_deg in the global frame."""
        with self._lock:
            return self._rover

    def rover_rest(self) -> tuple[float, float, float]:
        """Height, roll and pitch (deg) of the rover's body resting on the terrain under its
        wheels where it truly stands (:func:`~drivers.sim.rover.resting_pose`): the pose every
        frame is rendered from, and the attitude its IMU reads. Held until the rover, its body
        or the terrain change: every frame and every IMU read asks."""
        with self._lock:
            key = (self._rover, self.body, self.terrain)
            if self._rest is None or any(a is not b for a, b in zip(self._rest[0], key, strict=True)):
                self._rest = (key, resting_pose(self.body, self.terrain.sample, self._rover))
            return self._rest[1]

    def rover_z(self) -> float:
        """Height of the rover frame origin: where its wheels' plane meets its centre."""
        return self.rover_rest()[0]

    def rover_attitude(self) -> tuple[float, float]:
        """Roll (left side up) and pitch (nose up), deg, of the resting body: what its IMU reads."""
        return self.rover_rest()[1:]

    def set_rover_pose(self, x: float, y: float, heading_deg: float) -> None:
        """Put the rover there, and its odometry with it (a placement, not a drive)."""
        with self._lock:
            self._rover = (float(x), float(y), _wrap180(float(heading_deg)))
            self._odom = self._rover

    def move_rover(self, dx: float, dy: float, dyaw_deg: float) -> None:
        """Move by (dx forward, dy left) in the rover's current frame, then turn by dyaw.

        A teleport (no time passes, no slip): the odometry moves by the same commanded amount."""
        with self._lock:
            self._rover = _move(self._rover, dx, dy, dyaw_deg)
            self._odom = _move(self._odom, dx, dy, dyaw_deg)

    def odometry(self) -> tuple[float, float, float]:
        """x, y, heading_deg the rover believes it is at (dead reckoning from its wheels)."""
        with self._lock:
            return self._odom

    def set_odometry(self, x: float, y: float, heading_deg: float) -> None:
        """Reset the dead-reckoned pose (a GNC that accepts a fix from VO or map matching)."""
        with self._lock:
            self._odom = (float(x), float(y), _wrap180(float(heading_deg)))

    def set_slip(self, distance: float, heading: float, seed: int) -> None:
        """Wheel slip (share of distance lost) and heading drift (deg per metre), seeded."""
        with self._lock:
            self.slip = Slip(float(distance), float(heading), int(seed))

    def turn_toward(self, x: float, y: float, stop: Callable[[], bool] | None = None,
                    on_step: Callable[[], None] | None = None) -> float:
        """Turn on the spot, at the drive model's turn rate, until the rover believes (by its
        odometry) it faces (x, y); returns the distance it believes is left to drive. The one
        way a waypoint is approached, whichever loop drives the rover. ``on_step`` runs after
        each step of the turn, as in :meth:`drive` (a turn on the spot is motion too)."""
        ox, oy, heading = self.odometry()
        dist = math.hypot(x - ox, y - oy)
        if dist >= 1e-6:
            turn = (math.degrees(math.atan2(y - oy, x - ox)) - heading + 180.0) % 360.0 - 180.0
            if abs(turn) > 1e-9:
                rate = self.drive_model.turn_rate
                self.drive(0.0, math.copysign(rate, turn), abs(turn) / rate, stop, on_step=on_step)
        return dist

    def drive(self, v: float, w_deg: float, seconds: float, stop: Callable[[], bool] | None = None,
              on_step: Callable[[], None] | None = None) -> dict[str, float]:
        """Drive at forward speed ``v`` (m/s) and turn rate ``w_deg`` (deg/s) for ``seconds`` of
        simulated time, in steps of ``drive_model.step`` on the world's clock.

        The odometry integrates the command exactly; the truth integrates it through the slip
        model. ``stop()`` true ends the drive at the next step (a break); ``on_step`` runs after
        each step (a track recorder). Only one drive runs at a time: a second waits for the first.
        Returns the simulated seconds driven, the commanded distance and turn.
        """
        if seconds < 0 or not math.isfinite(seconds):
            raise ValueError("seconds must be a finite number >= 0")
        step = self.drive_model.step
        driven = 0.0
        what = "drive" if v > 0 else "reverse" if v < 0 else "turn on the spot" if w_deg else "stand"
        with self._drive_lock:
            n = max(1, math.ceil(seconds / step - 1e-9)) if seconds > 0 else 0
            for k in range(n):
                dt = min(step, seconds - k * step)
                if not self.clock.sleep(dt, stop, what):
                    break
                ds, dyaw = v * dt, w_deg * dt
                with self._lock:
                    self._odom = step_pose(self._odom, ds, dyaw)
                    true_ds, true_dyaw = self.slip.apply(ds, dyaw)
                    self._rover = step_pose(self._rover, true_ds, true_dyaw)
                driven += dt
                if on_step is not None:
                    on_step()
        return {"seconds": driven, "distance": v * driven, "turned": w_deg * driven}

    @contextlib.contextmanager
    def under_way(self) -> Iterator[None]:
        """A drive loop that checks its sensors between short drive calls: on a real rover those
        frames are exposed while it rolls, so a frame costs no time of its own (the ToF's exposure
        overlaps the drive) instead of the rover standing still for each."""
        with self._lock:
            self._under_way += 1
        try:
            yield
        finally:
            with self._lock:
                self._under_way -= 1

    @property
    def rolling(self) -> bool:
        """Whether a drive is under way (see :meth:`under_way`) or a drive call runs."""
        return self._under_way > 0 or self.driving

    @property
    def driving(self) -> bool:
        """Whether a drive is under way."""
        return self._drive_lock.locked()

    def add_rock(self, x: float, y: float, radius: float, height: float) -> dict[str, float]:
        """Place a rock at run time (a hazard the last scan did not see): the heightfield, and so
        every renderer and ``true_dem``, has it from the next frame on. Returns its record."""
        # The new heightfield and its shadows take 0.2-0.6 s of CPU (seconds on a loaded machine):
        # made outside the world's lock, which the rover's pose, the PTU's moves and every frame
        # take, so a drive, a PTU reply and a grab go on meanwhile; swapped in under it, made again
        # if a scene was loaded in between. One rock at a time keeps the rocks' seeded shapes.
        with self._rock_lock:
            while True:
                with self._lock:
                    base, rng, sun = self.terrain, self._rock_rng, self.sun
                terrain = _with_shadows(add_rock(base, x, y, radius, height, rng), sun)
                with self._lock:
                    if self.terrain is base:  # else a scene was loaded, with a rock generator of its own
                        self.terrain = terrain
                        return dict(terrain.rocks[-1])

    def truth(self) -> dict[str, float]:
        """The true state for ``sim truth``: x, y, z, heading, roll and pitch (deg) of the rover in
        the global frame (:meth:`rover_rest`) and the PTU's pan and tilt (deg), read together
        under the lock; also the dead-reckoned pose (odom_x, odom_y, odom_heading) and the
        simulated time."""
        with self._lock:
            x, y, h = self._rover
            ox, oy, oh = self._odom
            z, roll, pitch = self.rover_rest()
            return {"x": x, "y": y, "z": z, "heading": h, "roll": roll, "pitch": pitch, "pan": self._pan,
                    "tilt": self._tilt, "odom_x": ox, "odom_y": oy, "odom_heading": oh, "sim_time": self.clock.now()}

    def T_world_rover(self) -> np.ndarray:
        """The rover's body as it rests where it stands (:meth:`rover_rest`), tilted with it."""
        with self._lock:
            x, y, h = self._rover
            z, roll, pitch = self.rover_rest()
        return make_T(rover_rotation(h, roll, pitch), (x, y, z))

    def sensor_pose(self, sensor: str) -> np.ndarray:
        """T_world_from_camera (OpenCV optical frame) of "tof", "left" or "right"."""
        with self._lock:
            return self.sensor_pose_at(sensor, self._pan, self._tilt)

    def camera_intrinsics(self, sensor: str, width: int, height: int) -> np.ndarray:
        return self.head.intrinsics(sensor, width, height)

    def true_calibration(self, sensor: str, width: int, height: int) -> CameraTruth:
        with self._lock:
            pan, tilt = self._pan, self._tilt
            T_rc = self.head.T_rover_from_sensor(sensor, pan, tilt)
            return CameraTruth(self.head.intrinsics(sensor, width, height), np.zeros(5),
                               self.T_world_rover() @ T_rc, self.head.mounts[sensor].copy(), T_rc)

    def true_stereo_extrinsics(self) -> tuple[np.ndarray, np.ndarray]:
        """(R, T) as cv2.stereoCalibrate returns them: X_right = R X_left + T."""
        T = invert(self.head.mounts["right"]) @ self.head.mounts["left"]
        return T[:3, :3], T[:3, 3]

    # -- target and checkerboard -------------------------------------------------------------
    def set_target_time(self, t: float) -> None:
        """Put the target where its trajectory is at time t (seconds)."""
        with self._lock:
            self._target_time = float(t)

    def set_target_visible(self, visible: bool) -> None:
        """Show or hide the target (scenes may start with it hidden to keep DEMs clean)."""
        with self._lock:
            if self._target_obj is not None:
                self._target_obj.visible = bool(visible)

    def target_time(self) -> float:
        with self._lock:
            return self._target_time

    def target_pose(self) -> tuple[float, float, float, float] | None:
        """x, y, z (ground under it), heading_deg of the target now; None if the scene has none."""
        with self._lock:
            if self._trajectory is None:
                return None
            x, y, h = self._trajectory.at(self.target_time())
            z = float(self.terrain.sample(x, y))
            return x, y, (z if np.isfinite(z) else 0.0), h

    def place_checkerboard(self, T_world_board: np.ndarray, rows: int, cols: int, square: float,
                           margin: float | None = None) -> None:
        """Show a calibration board: ``rows`` x ``cols`` squares of side ``square``.

        Board frame as OpenCV's object points: origin at the outer corner of the square grid,
        x along the columns, y along the rows, z into the board (the camera looks at it along
        +z). The top-left square is dark; a white margin (default one square) surrounds them.
        """
        margin = square if margin is None else float(margin)
        shape = Rect(-margin, cols * square + margin, -margin, rows * square + margin)
        obj = SceneObject("checkerboard", CHECKERBOARD_ID, [shape], checker_albedo(rows, cols, square, margin),
                          np.asarray(T_world_board, float).copy(), in_dem=False, texture=0.0)
        with self._lock:
            self._board = obj
            self._board_geom = (obj.pose.copy(), int(rows), int(cols), float(square))

    def remove_checkerboard(self) -> None:
        with self._lock:
            self._board = None
            self._board_geom = None

    def checkerboard_corners(self) -> np.ndarray:
        """World coordinates of the inner corners ((rows-1)*(cols-1) x 3), in the order
        cv2.findChessboardCorners returns them for pattern size (cols-1, rows-1)."""
        with self._lock:
            if self._board_geom is None:
                raise RuntimeError("no checkerboard placed")
            T, rows, cols, sq = self._board_geom
        ii, jj = np.meshgrid(np.arange(1, rows), np.arange(1, cols), indexing="ij")
        pts = np.stack([jj.ravel() * sq, ii.ravel() * sq, np.zeros(ii.size)], axis=1)
        return transform(pts, T)

    # -- rendering and truth -----------------------------------------------------------------
    def _snapshot(self) -> tuple[Heightfield, list[SceneObject], Detail]:
        """Objects with their poses frozen at this instant (copies, so later moves don't leak in)."""
        with self._lock:
            objs = list(self._objects)
            rover = copy.copy(self._rover_obj)
            rover.pose = self.T_world_rover()
            objs.append(rover)
            pose = self.target_pose()
            if self._target_obj is not None and pose is not None:
                tgt = copy.copy(self._target_obj)
                x, y, z, h = pose
                tgt.pose = make_T(rot_z(h), (x, y, z))
                objs.append(tgt)
            if self._board is not None:
                objs.append(self._board)
            return self.terrain, objs, self.detail

    def render(self, K: np.ndarray, width: int, height: int, T_world_cam: np.ndarray,
               cancel: Callable[[], bool] | None = None) -> Render:
        """``cancel``: see drivers.sim.render.render (a grab a break may stop)."""
        hf, objs, detail = self._snapshot()
        return render(hf, objs, detail, K, int(width), int(height), T_world_cam, cancel)

    def render_sensor(self, sensor: str, width: int, height: int) -> Render:
        """Render what a sensor sees now with its true intrinsics (PTU and rover read once)."""
        with self._lock:
            K = self.camera_intrinsics(sensor, width, height)
            T = self.sensor_pose(sensor)
            hf, objs, detail = self._snapshot()
        return render(hf, objs, detail, K, int(width), int(height), T)

    def true_dem(self, cell: float, bounds: tuple[float, float, float, float], include_objects: bool = True,
                 include_rover: bool = False, include_target: bool = False) -> np.ndarray:
        """Ground-truth heights on a north-up grid (float32).

        The grid has ``round((xmax-xmin)/cell)`` columns and ``round((ymax-ymin)/cell)`` rows;
        each value is the height at the cell centre: column j at x = xmin + (j + 0.5) cell, row
        i at y = ymax - (i + 0.5) cell (row 0 north, as in a GeoTIFF with pixel-is-area). It
        is the terrain's bilinear surface (rocks, steps, boxes, sandbox included) and, with
        ``include_objects``, the top of static objects that stand on the ground (walls and
        boxes: the highest point of the object above that cell centre). The rover, the target
        and a checkerboard are left out unless asked for. NaN off the terrain grid where no
        object stands.
        """
        xmin, ymin, xmax, ymax = bounds
        nx = int(round((xmax - xmin) / cell))
        ny = int(round((ymax - ymin) / cell))
        xs = xmin + (np.arange(nx) + 0.5) * cell
        ys = ymax - (np.arange(ny) + 0.5) * cell
        hf, objs, _ = self._snapshot()
        dem = hf.resample(xs, ys).astype(np.float64)
        keep = []
        for o in objs:
            if o.oid == 1:
                if include_rover:
                    keep.append(o)
            elif o.name == "target":
                if include_target and o.visible:
                    keep.append(o)
            elif o.in_dem and include_objects:
                keep.append(o)
        for o in keep:
            # Vertical rays from above, only over the cells under the object's bounding box.
            c = o.world_corners()
            cols = np.flatnonzero((xs >= c[:, 0].min()) & (xs <= c[:, 0].max()))
            rows = np.flatnonzero((ys >= c[:, 1].min()) & (ys <= c[:, 1].max()))
            if cols.size == 0 or rows.size == 0:
                continue
            X, Y = np.meshgrid(xs[cols], ys[rows])
            ztop = float(c[:, 2].max()) + 1.0
            orig = np.stack([X.ravel(), Y.ravel(), np.full(X.size, ztop)], axis=1)
            down = np.tile([0.0, 0.0, -1.0], (X.size, 1))
            t, _, _ = o.intersect(orig, down)
            z = (ztop - t).reshape(X.shape)  # -inf where the ray missed
            sub = dem[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
            higher = np.isfinite(z) & (np.isnan(sub) | (z > sub))
            sub[higher] = z[higher]
        return dem.astype(np.float32)


# The ground a scene builds (its terrain with the shadows, the shift to the start, the detail
# tile), by scene and seed: a process that builds a scene again (a test's next server, a load-scene
# back to it) takes it from here rather than spending its CPU again (0.1 s office, 2 s quarry).
# Worlds may share one: nothing changes a built heightfield in place (add_rock makes a copy).
_GROUNDS: dict[str, tuple[Heightfield, float, np.ndarray]] = {}
GROUNDS_KEPT = 3  # the scenes last built (a quarry's ground holds some 50 MB)
_GROUNDS_LOCK = threading.Lock()


def _ground(spec: dict, seed: int, look: SceneLook) -> tuple[Heightfield, float, np.ndarray]:
    """The scene's terrain (shifted so the rover's origin at its start is z = 0, with its
    shadows), that shift, and the render's detail tile."""
    key = json.dumps([spec, seed], sort_keys=True, default=repr)
    with _GROUNDS_LOCK:
        kept = _GROUNDS.pop(key, None)
        if kept is not None:
            _GROUNDS[key] = kept  # the most recent last
            return kept
    rng = np.random.default_rng(seed)
    terrain = build_terrain(spec["terrain"], rng, base_dir=spec.get("_dir"), albedo=look.albedo)
    # The global frame's origin is the rover frame's at its start (where the plane its wheels
    # rest on meets its centre, z up from there), as the server assumes of a rover with no map
    # yet; scenes are shifted to it.
    rover_spec = spec.get("rover", {})
    start_spec = rover_spec.get("start", {})
    start = (float(start_spec.get("x", 0.0)), float(start_spec.get("y", 0.0)), float(start_spec.get("heading", 0.0)))
    z0 = resting_pose(RoverBody.from_spec(rover_spec.get("body")), terrain.sample, start)[0]
    if not np.isfinite(z0):
        z0 = 0.0
    if z0 != 0.0:
        terrain = Heightfield(terrain.x0, terrain.y0, terrain.cell, terrain.heights - np.float32(z0),
                              terrain.albedo, rocks=terrain.rocks)
    terrain = _with_shadows(terrain, look.sun)
    tile = periodic_tile(512, rng)  # drawn either way: one seed, one world
    if look.albedo.source == "mars" and look.albedo.detail:
        rel = load_texture(data_file(look.albedo.texture, Path(spec["_dir"]) if "_dir" in spec else None))
        tile = np.clip(0.5 + 0.5 * (rel - 1.0), 0.0, 1.0).astype(np.float32)
    with _GROUNDS_LOCK:
        _GROUNDS[key] = (terrain, z0, tile)
        while len(_GROUNDS) > GROUNDS_KEPT:
            _GROUNDS.pop(next(iter(_GROUNDS)))
    return terrain, z0, tile


def _with_shadows(terrain: Heightfield, sun: SunSettings) -> Heightfield:
    """The terrain with its sun-visibility map when the scene casts shadows (computed once per
    terrain: the sun does not move during a scene)."""
    if sun.shadows:
        terrain.sunlit = sunlit_map(terrain.heights, terrain.cell, sun.azimuth_deg, sun.elevation_deg)
    return terrain


def _wrap180(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def _move(pose: tuple[float, float, float], dx: float, dy: float, dyaw: float) -> tuple[float, float, float]:
    x, y, h = pose
    c, s = np.cos(np.radians(h)), np.sin(np.radians(h))
    return (float(x + c * dx - s * dy), float(y + s * dx + c * dy), _wrap180(h + dyaw))
