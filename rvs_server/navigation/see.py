"""The seeing driver of the see loop (``navigate -loop see``): :class:`SeeingDriver` takes the
frames (the ToF's, and the body's hazard cameras' where switched on) and fuses them into the
rolling 5 cm map and the chooser's bounds map, runs the check of the next metres, points the
mast where the look planner (:mod:`prox_workflows.algorithms.looks`) says and sends the stop
EVENT. What drives with it: the chooser's sections (:mod:`.sections`, ``see_gate bounds``, the
default) or the legs planned on the 5 cm maps (:mod:`.map_legs`, ``see_gate off``); what keeps it for the
mission: the see strategy (:mod:`.see_strategy`).

On the 5 cm maps the rover drives a leg in cycles (the simulated rover: every ``see_period`` of
driving; the GNC: each pose it reports while driving); each cycle one forward ToF frame feeds
the rolling local elevation map, Dem2Hazard updates the window the frame touched, and the
rover's footprint is swept over the next metres of its path. A hazard there stops the rover (an
``EVENT kind=hazard level=stop`` shaped as the hazard monitor's) and navigate replans from the
scan maps with the rolling map laid over them, instead of stopping for a 360-degree scan at the
end of every leg (seed 000 sect. 6.2; Perseverance's ENav "thinking while driving").

Why the cycle looks as it does
    - The rover drives ``see_period`` of simulated time, then the ToF takes its frame, then the
      check runs; the check's CPU time is measured as the cycle latency (target < 100 ms). The
      frame is exposed while the rover rolls (``World.under_way``): it costs no standing time,
      as on a rover whose camera works while it drives; a frame taken standing (a look round
      before a 360-degree scan) costs its time on the clock.
    - The rover steers by pure pursuit: small heading changes are driven as arcs, only large
      ones are turned on the spot, so replanning on the move costs no stop.
    - The check looks ``see_lookahead`` metres ahead along the remaining waypoints, so a hazard
      is met while still farther than ``stop_distance`` plus one cycle's travel: the stop comes
      before the rover is within its stopping distance.
    - Only ``not_traversable`` stops the rover: the plan was made on the scan maps, which the
      rolling map only refines; unseen cells (the blind patch under the view) are the plan's,
      unless ``see_unseen`` says to look at them first (and with ``keep``, to plan round them).
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.base import DeviceError
from drivers.tof.constants import FOV_H_DEG, FOV_V_DEG
from prox_workflows.algorithms import looks
from prox_workflows.algorithms.bounds_map import BoundsMap
from prox_workflows.algorithms.hazard_monitor import ground_pixels, rover_points
from prox_workflows.algorithms.looks import BODY_MARGIN, View, on_body
from prox_workflows.algorithms.noise import pair_sigmas, tilt_spread, tof_spread
from prox_workflows.algorithms.planner import NavMaps
from prox_workflows.algorithms.rolling_map import (
    MapMemory,
    RollingMap,
    RollingParams,
    path_poses,
    sweep_check,
)
from prox_workflows.algorithms.safety import in_footprint
from prox_workflows.algorithms.transforms import HeadCalibration, T_global_from_rover, in_rover_frame

from ..bus import tapped_call
from ..jobs import device_call
from ..maps import ground_height
from ..protocol import Fixed, Reply
from .sections import WINDOW_SLACK

if TYPE_CHECKING:
    from drivers.hazcam import HazcamFrame

    from ..app import App
    from ..jobs import Job
    from .config import SeeConfig
    from .loop_stats import LoopStats


EDGE_JUMP = 0.02  # share of the range: a bigger jump to a neighbouring pixel marks a depth edge's mixed pixel
BLIND_EDGE = 0.1  # m past the mast's blind disc that its rays only graze (bounded by a ray, seldom by returns)
STILL = 0.005  # m: a pose this close to the last frame's is the same stand (a look round, a turn on the spot)
RING_WIDTH = 0.5  # m past the blind disc: the seen ground whose plane see_set_down ring takes


def map_pairs(app: App) -> list[str]:
    """The hazard camera pairs whose frames feed the see loop's map.

    A simulated pair renders the simulator's world, which is the rover's only where the mast's
    ToF is simulated too: beside a real (or replayed) ToF it would lay that world into a real
    rover's map, where the wheels trust it. That configuration is refused, not quietly dropped,
    since the operator who left it believes the pairs guard the rover's start."""
    devices = app.devices
    if "hazcam" not in devices.devices:
        return []
    hazcam = devices.get("hazcam")
    pairs = list(hazcam.cameras())
    tof = devices.devices["tof"].backend if "tof" in devices.devices else devices.section("tof").backend
    if pairs and hazcam.backend == "sim" and tof != "sim":
        raise DeviceError("hazcam", f"the hazard cameras are simulated and the ToF is {tof}: a simulated pair "
                                    "must not feed a real rover's map; set drivers.hazcam.cameras off, or "
                                    "drivers.hazcam.backend dc1394 for the rover's own pairs, and reinit -device "
                                    "hazcam")
    return pairs


class SeeingDriver:
    """One navigate's see loop: the rolling map lives for the whole mission."""

    def __init__(self, job: Job, rover: Any, params: SeeConfig, stats: LoopStats,
                 memory: MapMemory | None = None, bounds: BoundsMap | None = None) -> None:
        self.job = job
        self.app: App = job.app
        self.rover = rover
        self.body = rover.body()
        # the chooser's map (see_gate bounds): every frame's bounds over a window that follows the rover
        self.bounds = bounds
        self.set_down_pending = False  # see_set_down ring: the set-down waits for the first look round
        # the body's hazard cameras switched on (drivers.hazcam.cameras): each frame feeds the bounds
        self.hazcams: list[str] = map_pairs(self.app) if bounds is not None else []
        self.p = params
        self.stats = stats
        head = self.app.config.get("head")
        self.length = head.rover_length + 2 * params.margin
        self.width = head.rover_width + 2 * params.margin
        self.head = HeadCalibration.from_dict(head.as_dict())
        here = self.pose()
        self.map = RollingMap(RollingParams(), self.app.config.get("dem2hazard"), (here[0], here[1]), memory)
        # the body turning on the spot, with the cells its corners touch
        self.radius = math.hypot(head.rover_length, head.rover_width) / 2 + self.map.params.cell
        self.level = "clear"
        self.pan_tilt = (0.0, params.tilt)  # where the ToF points (what the PTU reached)
        self.frame_no = 0  # frames taken while driving (the gaze alternates far and near)
        self.slewing: tuple[float, float] | None = None  # where the PTU was sent without waiting (settle)
        self.cpu1 = 0.0  # the process time the last frame's fusion started (a cycle's CPU is counted from it)
        # the maps the leg was planned on (the scans and the rolling map then) on the rolling map's
        # grid, as traversability: the check counts the ground they saw as seen
        self.known: NavMaps | None = None
        self.seen: tuple[Any, Any, np.ndarray] | None = None  # (known, geometry, layer) of the last resampling
        self.looked_from: tuple[float, float, float] | None = None  # the pose of the last look at unseen ground
        # (x, y, z) the last frame put the rover frame's origin at: a rover that has not moved since
        # stands at that height, whatever the map round it says now that the frames have filled it
        self.held: tuple[float, float, float] | None = None
        # the pose of the last frame's stand (BoundsMap.stood): the body passed over the ground
        # from there to the next (None: set down, where nothing was driven over)
        self.stood_at: tuple[float, float, float] | None = None

    def point_forward(self) -> None:
        """The PTU to pan 0 (the rover's forward), tilted down: the ToF looks where the rover goes."""
        self._point(0.0)

    def _point(self, pan: float, tilt: float | None = None) -> None:
        reached = device_call(self.job, self.app.devices.get("ptu").move, pan,
                              self.p.tilt if tilt is None else tilt, True)
        self.pan_tilt = (float(reached[0]), float(reached[1]))
        self.slewing = None

    def gaze(self, pose: tuple[float, float, float], remaining: np.ndarray, wait: bool = True) -> None:
        """The PTU to where the ToF looks for the next frame taken while driving (``see_gaze
        path``: :func:`looks.gaze`, near frames at the PTU's lowest tilt, far ones at
        ``see_tilt``), the rover at ``pose`` when it is taken. ``wait`` False: sent on without
        waiting, so that the mast slews while the rover drives the cycle's motion (:meth:`settle`
        before the frame). Off, or without the bounds map (which the near frames feed): pan 0,
        ``see_tilt``, and no PTU move between frames."""
        if not self.gazes:
            return
        self.frame_no += 1
        aim = looks.gaze(self.frame_no, pose, remaining, self.head, self.pan_tilt, (self._lowest_tilt(), self.p.tilt),
                         self.p.gaze_hold)
        if aim is None:
            return
        if wait:
            self._point(*aim)
        else:
            device_call(self.job, self.app.devices.get("ptu").move, aim[0], aim[1], False)
            self.slewing = aim

    @property
    def gazes(self) -> bool:
        """The mast moves between the frames taken while driving (:meth:`gaze`)."""
        return self.p.gaze != "off" and self.bounds is not None

    def settle(self) -> None:
        """Wait for the PTU where :meth:`gaze` sent it without waiting: no frame is taken while the
        mast slews. A slew that ended while the rover drove costs nothing more."""
        if self.slewing is None:
            return
        reached = device_call(self.job, self.app.devices.get("ptu").wait)
        self.pan_tilt = (float(reached[0]), float(reached[1]))
        self.slewing = None

    def pose(self) -> tuple[float, float, float]:
        """The rover's belief: the simulated rover's odometry, the GNC's last pose report."""
        return self.rover.pose()

    def see(self, pan_tilt: tuple[float, float], cameras: tuple[str, ...] = ("front",), frames: int = 1
            ) -> tuple[tuple[float, float, float], float]:
        """One ToF frame (the camera's average of ``frames``) into the rolling map, and into the
        bounds map (if kept) with a frame of each of the hazard ``cameras`` switched on (driving:
        the front pair, which sees the ground the wheels meet next); returns the rover's pose and
        the wall time (monotonic) the fusion started. Each return's sigma is the ToF's noise
        model's at its own amplitude (as the device says the noise goes with it) over the frames
        averaged, its horizontal error along its ray. The returned time is moved on by each pair's
        capture (the simulator's render of it, a real pair's exposure): from it to the verdict is
        the cycle's own work (``LoopStats.cycle``)."""
        job, app = self.job, self.app
        t0 = time.monotonic()
        tof = app.devices.get("tof")
        xyz, amplitude = device_call(job, tof.grab_xyz, frames, 0.0)
        t1 = time.monotonic()
        self.cpu1 = time.process_time()  # the cycle's CPU from here (LoopStats.cycle)
        x, y, heading = self.pose()
        T_rc = self.head.T_rover_from_sensor("tof", *pan_tilt)
        pts = rover_points(xyz, T_rc, self.p.subsample, self.p.max_range, amplitude, 0.1)
        ranges = np.linalg.norm(pts - T_rc[:3, 3].astype(np.float32), axis=1)
        standing = self.standing(x, y)
        imu = self.imu()  # one read for the frame: its pairs ride on the same body
        roll, pitch, tilt_sigma = imu if imu is not None else (0.0, 0.0, 0.0)
        T = T_global_from_rover(x, y, heading, self.stand_height(x, y), roll, pitch)
        if self.bounds is not None:
            self.bounds.follow(x, y, WINDOW_SLACK)
            # every pixel: a rock's top is read by the few returns on it, which a subsample drops
            keep = ground_pixels(xyz, 1, self.p.max_range, amplitude, 0.1, EDGE_JUMP)
            cam = xyz[keep].astype(np.float64)
            full = cam @ T_rc[:3, :3].T + T_rc[:3, 3]
            ground = ~self.on_body(full)
            full = full[ground] @ T[:3, :3].T + T[:3, 3]
            rise = None if standing or not self.p.register else self.bounds.offset(full)
            if rise is not None:  # placed on the ground the map holds, not on the height read round the centre
                T[2, 3] -= rise
                full[:, 2] -= rise
            origin = T[:3, :3] @ T_rc[:3, 3] + T[:3, 3]
        self.held = (x, y, float(T[2, 3]))
        world_pts = pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        self.map.follow(x, y)
        self.map.fuse(world_pts, ranges)
        if self.bounds is not None:
            raw, mhz = tof.noise_amplitude(amplitude[keep][ground], np.linalg.norm(cam[ground], axis=1))
            sigma, along, across = tof_spread(full, origin, raw, frames=frames, frequency_mhz=mhz)
            sigma = np.hypot(sigma, tilt_spread(full, T[:3, 3], tilt_sigma))
            self.bounds.fuse(full, sigma, origin, self.p.max_range, along, sigma_across=across)
            for camera in (c for c in self.hazcams if c in cameras):
                frame = self._fuse_hazcam(camera, T, tilt_sigma)
                # the pair's capture is the sensor's time, as the ToF frame's is: the cycle starts later by it
                t1 += frame.capture_s
                self.cpu1 += frame.capture_cpu_s
            if not self.set_down_pending:
                self.bounds.stood((x, y, heading), float(T[2, 3]), self.body, self.attitude(imu), since=self.stood_at)
                self.stood_at = (x, y, heading)
            app.bus.publish("bounds", bounds=self.bounds)  # Foxglove and recordings (their hub throttles)
        self.stats.frame_ms.append((t1 - t0) * 1000)  # the ToF frame's and the pairs' captures
        return (x, y, heading), t1

    def cycle(self, remaining: np.ndarray) -> tuple[Any, Any, tuple[float, float, float]]:
        """One frame into the rolling map and the check of the next metres; returns the check,
        the unseen check (:meth:`judge`) and the pose."""
        pose, t1 = self.see(self.pan_tilt)
        check, unseen = self.judge(pose, remaining)
        self.stats.cycle(t1, self.cpu1)
        return check, unseen, pose

    def judge(self, pose: tuple[float, float, float], remaining: np.ndarray,
              motion: np.ndarray | None = None) -> tuple[Any, Any]:
        """The footprint swept along the motion the rover executes next (``motion``, poses from
        ``pose``: this cycle's arc or turn on the spot; by default the turn from its heading to
        the path's) and on along the path for the next ``lookahead`` metres (blocked anywhere
        stops the rover), and for the next ``blind`` metres: the check of that stretch when it
        covers ground no map has seen, else None. The executed arc cuts the path's corners and
        a turn on the spot swings the body's corners wide: the planned polyline alone leaves
        that ground unchecked. The forward view starts about a metre ahead of the rover (1.1 m
        from its centre at tilt -35 deg), so ground that close and still unseen will not be
        seen before the body is on it: a rock the rover turned to face, or one round the corner
        of its path."""
        trav, g = self._check_layer(pose), self.map.geometry
        lead = np.asarray([pose] if motion is None else motion, dtype=np.float64).reshape(-1, 3)

        def along(distance: float) -> np.ndarray:
            return np.vstack([lead, path_poses(tuple(lead[-1]), remaining, distance)])

        check = sweep_check(trav, g, along(self.p.lookahead), self.length, self.width)
        if self.p.unseen == "off" or self.p.blind <= 0.0:
            return check, None
        near = sweep_check(trav, g, along(self.p.blind), self.length, self.width)
        return check, near if near.verdict == "unknown" else None

    def _fuse_hazcam(self, camera: str, T: np.ndarray, tilt_sigma: float) -> HazcamFrame:
        """One body hazard camera's pair into the bounds map (with the rover at ``T``, its attitude
        good to ``tilt_sigma`` deg): the ground from about 0.1 m past the body's end, where the
        mast never sees. Each point's range sigma
        is the disparity noise's (it grows with the range squared), and the frame is fused as a
        stereo frame: a cell's pixels share the matcher's window, so their errors are one error.
        Fused as independent returns, 60 % of the cells' means round the body at mission starts
        lay more than 3 sigma off the true surface and 7-16 % of the cells had the truth under
        their lower bound; as stereo about 1 % and at most 0.2 % (``python -m tools.bench.hazcam
        --ring``).
        Its cells fuse with the ToF's and the set-down's prior by their variances (the prior's
        1-3.7 cm leaves the cell the pair's reading)."""
        device = self.app.devices.get("hazcam")
        frame = device_call(self.job, device.grab, camera)
        ground = ~self.on_body(frame.points)
        pts = frame.points[ground] @ T[:3, :3].T + T[:3, 3]
        origin = T[:3, :3] @ frame.origin + T[:3, 3]
        sigma, sigma_xy = pair_sigmas(pts, origin, frame.sigma_range[ground], device.rig(camera).focal)
        sigma = np.hypot(sigma, tilt_spread(pts, T[:3, 3], tilt_sigma))
        self.bounds.fuse(pts, sigma, origin, device.config.max_range, sigma_xy, sensor="stereo")
        return frame

    def on_body(self, pts: np.ndarray) -> np.ndarray:
        """Rover-frame points on the rover itself (its box and wheels, a few centimetres grown):
        the mast looking down and back sees its own deck and wheels, which are not ground."""
        return on_body(pts, self.body, BODY_MARGIN)

    def standing(self, x: float, y: float) -> bool:
        """The rover stands where it took the last frame (a look round, a turn on the spot)."""
        return self.held is not None and math.hypot(x - self.held[0], y - self.held[1]) <= STILL

    def stand_height(self, x: float, y: float) -> float:
        """The height the frames put the rover frame's origin at, standing at (x, y): :meth:`datum`;
        with ``see_register``, where the last frame was taken, the height it was placed at, and
        elsewhere :meth:`datum` until the frame is placed on the ground the map holds
        (:meth:`BoundsMap.offset <prox_workflows.algorithms.bounds_map.BoundsMap.offset>`)."""
        return self.held[2] if self.p.register and self.held is not None and self.standing(x, y) else self.datum(x, y)

    def datum(self, x: float, y: float) -> float:
        """The height the frames take the rover's own ground at (x, y): the rolling map's there,
        else the global maps'. The rover frame's origin: where its wheels' plane meets its centre."""
        z = self.map.ground_height(x, y)
        return ground_height(self.app.maps.layers, x, y) if z is None else z

    def imu(self) -> tuple[float, float, float] | None:
        """Roll, pitch and their sigma (deg) from the rover's IMU where it stands, or None (the
        rover gives none: a GNC whose pose reports carry no roll and pitch)."""
        attitude = getattr(self.rover, "attitude", None)
        # a device call like a frame: a recording holds the tilt each frame was placed with
        return tapped_call(self.app.bus, attitude) if attitude is not None else None

    def attitude(self, imu: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
        """The IMU's attitude (``imu``, a read of :meth:`imu`) for the ground under the wheels
        while driving, or None (``see_set_down level``: the wheels' ground is then the frames' and,
        where none, level within 5 mm of the frame's height). With an attitude the body rests on
        the ground frames bounded under its wheels (:meth:`BoundsMap.stood`), not on the frame's
        height at its centre: taken level through that height, a wheel's unseen ground stood 7 cm
        over the truth on a slope and the check refused the very pose the rover stood on."""
        return None if self.p.set_down == "level" else imu

    def _check_layer(self, pose: tuple[float, float, float]) -> np.ndarray:
        """The traversability the check sweeps: the rolling map's, lowered to 0 where the maps the
        leg was planned on say hazardous, and theirs where the rolling map has none (resampled
        when either changes); the ground under the body counts as seen: it stands there. Never
        less cautious than the rolling map alone (a scan's verdict does not clear what the
        rolling map saw, as it does in the plan: a marsyard mission then drove over a 20.0 deg
        cell the scan had judged safe). Only the body's own rectangle, not the disc it sweeps
        turning on the spot: that disc holds ground beside the body the forward ToF never
        showed, a rock's flank the rover turned beside (hirise mission 4 drove over 364 such
        cells); unseen, see_unseen looks at it before the body goes there."""
        g = self.map.geometry
        if self.known is None:
            layer = self.map.traversability.copy()
        else:
            if self.seen is None or self.seen[0] is not self.known or self.seen[1] != g:
                self.seen = (self.known, g, self.map.seen_by(self.known))
            layer = np.fmin(self.map.traversability, self.seen[2])
        xs, ys = g.centers()
        under = in_footprint(xs[None, :] - pose[0], ys[:, None] - pose[1], pose[2], self.length, self.width, g.cell)
        layer[under & np.isnan(layer)] = 1.0
        return layer

    def _lowest_tilt(self) -> float:
        return self.view().lowest_tilt

    def blind_disc(self) -> tuple[float, float, float]:
        """The ground round the mast's foot that no frame shows, even at the PTU's lowest tilt
        (:func:`looks.blind_disc`): (x, y) of the pan axis's foot and the radius, by the head's
        calibration."""
        return looks.blind_disc(self.pose(), self.head, self.view())

    def view(self) -> View:
        """The ToF's field of view and the PTU's reach, for the look planner."""
        return View.of_ptu(self.app.devices.get("ptu").limits(), FOV_H_DEG, FOV_V_DEG)

    def look_at(self, x: float, y: float, pose: tuple[float, float, float], what: str = "unseen ground") -> bool:
        """One frame (``see_look_frames`` averaged), standing, toward ground point (x, y)
        (:func:`looks.look_at`, tilted no lower than the PTU goes and no higher than
        ``see_tilt``); ``what`` the ground is, for the progress line. False (no frame) when the
        rover looked from about here already (:func:`looks.looked_from_here`)."""
        if looks.looked_from_here(self.looked_from, pose):
            return False
        self.looked_from = pose
        self.stats.looks += 1
        self.job.progress(0, 1, f"looking at {what} ({x:.2f}, {y:.2f}) before driving onto it", phase="drive")
        self._point(*looks.look_at(pose, x, y, self.head, self._lowest_tilt(), self.p.tilt))
        self.see(self.pan_tilt, (), self.p.look_frames)  # the body's cameras saw this cycle's ground already
        self.job.check()
        return True

    def look_round(self, toward: float | None = None) -> None:
        """A standing look (:func:`looks.round_look`): frames at the PTU's lowest tilt and at
        ``see_tilt`` over the pans that show the ground the body covers driving ``see_look_drive``
        about ``toward`` (deg from the heading; None: all round) and as far again, from the
        mast's blind disc out, but for ground the bounds map has already judged; each position
        ``see_look_frames`` frames averaged. After a scan: the scan's views make the 5 cm maps
        only. The mast stays at the last position: what drives next points it (the section's
        pilot, :class:`~.sections.SectionPilot`)."""
        positions = looks.round_look(self.pose(), self.head, self.view(), self.body, self.p.look_drive, self.p.tilt,
                                     toward, self.bounds, (self.slewing or self.pan_tilt)[0])
        if not positions:
            return
        self.stats.looks += 1
        self.job.progress(0, 1, f"looking standing: {len(positions)} positions of {self.p.look_frames} frames, the "
                                f"ground the next {self.p.look_drive:g} m need", phase="drive")
        cameras = tuple(self.hazcams)  # the body's cameras do not pan: one frame of each
        for pan, tilt in positions:
            self._point(pan, tilt)
            self.see(self.pan_tilt, cameras, self.p.look_frames)
            cameras = ()
            self.job.check()

    def look(self, bearing: float, spread: float = 40.0) -> None:
        """Frames panned to ``bearing`` (deg from the rover's heading) and ``spread`` either side
        (:func:`looks.look_pans`), the rover standing (each ``see_look_frames`` averaged): the
        rolling map's view round the forward one."""
        cameras = tuple(self.hazcams)
        for pan in looks.look_pans(bearing, spread):
            self._point(pan)
            self.see(self.pan_tilt, cameras, self.p.look_frames)
            cameras = ()
            self.job.check()

    def _stop_event(self, x: float, y: float, pose: tuple[float, float, float],
                    reason: str = "hazard") -> dict[str, Any]:
        """The stop EVENT, shaped as the hazard monitor's (distance from the rover's front to the
        hazard at global (x, y), bearing CCW from the heading, x and y in the rover frame), with
        why: ``hazard`` (the 5 cm maps' hazard), ``vehicle`` (the vehicle check on the bounds map:
        the body would exceed a limit at a pose ahead), ``unknown`` (ground no frame bounded
        under a pose ahead)."""
        rx, ry = in_rover_frame(pose, x, y)
        distance = max(0.0, rx - self.app.config.get("head").rover_length / 2 - self.map.params.cell / 2)
        self.stats.stops += 1
        fields = {"kind": "hazard", "level": "stop", "reason": reason, "distance": Fixed(distance, 2),
                  "bearing": Fixed(math.degrees(math.atan2(ry, rx)), 1), "x": Fixed(rx, 2), "y": Fixed(ry, 2),
                  "seen": "false" if reason == "unknown" else "true", "cycle": self.stats.cycles,
                  "job": self.job.id, "source": "navigate"}
        self.level = "stop"
        self.app.broadcast_threadsafe(Reply("RVS", "EVENT", fields))
        return {"distance": distance, "x": rx, "y": ry, "reason": reason}

    def _clear(self) -> None:
        if self.level != "clear":
            self.level = "clear"
            self.app.broadcast_threadsafe(Reply("RVS", "EVENT", {
                "kind": "hazard", "level": "clear", "cycle": self.stats.cycles, "job": self.job.id,
                "source": "navigate"}))

