"""One navigate (seed 000 sect. 4.4.4, appendix F): the legs from the start to the goal.

The mission owns what every leg shares: the rover (drivers/rover), the believed pose and its
localiser, the planner's parameters and the global maps, the 360-degree scans, the track and
the products. Its strategy (:mod:`.scan` or :mod:`.see_strategy`, behind :class:`.strategy.Strategy`)
plans and drives the legs between scans.
"""

from __future__ import annotations

import copy
import math
import time
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.base import DeviceInterrupted
from drivers.rover import Settle, Silent

from ..jobs import Interrupted
from ..protocol import Fixed, ProtocolError, Reply, Rows
from .localiser import Localiser, pose_fields
from .planning import load_global_maps, planner_params
from .scan import ScanStrategy
from .see_strategy import SeeStrategy
from .track import Track

if TYPE_CHECKING:
    from drivers.rover import Pilot, Rover

    from ..app import App
    from ..jobs import Job
    from .config import NavigateConfig
    from .strategy import Strategy


def rover_for(app: App, auto: bool) -> Rover:
    """The rover that drives this navigate: the configured one (drivers.rover), or with
    ``-auto`` the simulated one (the configured one if it drives -auto legs itself: the
    simulated one, or a replay of a recorded -auto leg)."""
    import drivers.rover

    rover = app.devices.get("rover")
    if not auto or rover.drives_auto:
        return rover
    sim = drivers.rover.create({"backend": "sim"}, app.world, app)
    sim.open()
    return sim


def check_request(app: App, cfg: NavigateConfig) -> None:
    """Refusals before the ACK."""
    from .planning import check_plan_size

    if cfg.auto and app.world is None and not app.devices.get("rover").drives_auto:
        raise ProtocolError("E_ARG", "-auto drives the simulated rover; with real hardware the GNC sends pose")
    check_plan_size(app, cfg)


class Mission:
    def __init__(self, job: Job, cfg: NavigateConfig, name: str, track: Track) -> None:
        self.job = job
        self.app: App = job.app
        self.cfg = cfg
        self.name = name
        self.track = track
        self.goal = (cfg.goal[0], cfg.goal[1])
        self.rover = rover_for(self.app, cfg.auto)
        self.global_maps, global_map = load_global_maps(cfg)
        self.loc = Localiser.configured(cfg.localisation, global_map, self.rover)
        self.params = planner_params(self.app, cfg.plan)
        self.paths: list[np.ndarray] = []  # each leg's planned path, as driven (to its cut)
        self.waypoints: list[np.ndarray] = []
        self.scans = 0
        self.leg_starts: list[tuple[float, float]] = []
        self.stalled = 0  # legs in a row that started where the previous one did
        self.announced_at: tuple[float, float, float] | None = None  # the pose the last waiting EVENT left from
        self._place()
        # made where the rover starts: the see strategy's maps cover the start and the goal
        chooser = cfg.loop == "see" or cfg.scan_plan == "chooser"
        self.strategy: Strategy = SeeStrategy(self) if chooser else ScanStrategy(self)
        self.app.bus.publish("mission", mission=self)

    def _place(self) -> None:
        """navigate -start: the rover is set down there."""
        app, cfg = self.app, self.cfg
        if cfg.start:
            heading = cfg.start[2] if len(cfg.start) == 3 else app.pose.heading
            app.set_pose(cfg.start[0], cfg.start[1], heading, source="navigate")
            self.rover.place((cfg.start[0], cfg.start[1], heading))

    # -- what the strategies share ---------------------------------------------------------
    def progress(self, leg: int, done: int, total: int, message: str, phase: str = "") -> None:
        self.job.progress(done, total, message, phase=phase, leg=leg)

    def record(self, path: np.ndarray, waypoints: np.ndarray) -> None:
        """A plan about to be driven: its path (as it will be driven) and its waypoints (x, y) go
        into the mission's products."""
        self.paths.append(path)
        self.waypoints.append(waypoints)

    def announce(self, leg: int, waypoints: Any, file: str, reverse: bool = False) -> int:
        """``EVENT kind=waiting`` with the leg's waypoints (the GNC drives them); returns the mark
        of the pose reports before it (a GNC may answer it at once). ``reverse``: the leg is driven
        backwards (the waypoints' headings are the body's, opposite to the way it moves), which
        the event says with ``drive=reverse``; a forward leg's event has no such field."""
        since = self.rover.mark()
        pose = self.app.pose
        self.announced_at = (pose.x, pose.y, pose.heading)
        rows = Rows((Fixed(x, 3), Fixed(y, 3), Fixed(h, 2)) for x, y, h in waypoints.table()[:, :3])
        self.app.broadcast_threadsafe(Reply("RVS", "EVENT", {
            "kind": "waiting", "job": self.job.id, "leg": leg, "waypoints": rows, "file": file,
            **({"drive": "reverse"} if reverse else {}), **pose_fields(self.job)}))
        return since

    def drive(self, pilot: Pilot, since: int, end: tuple[float, float]) -> tuple[float, float, float]:
        """One leg driven by the rover with ``pilot``; a break stops it (E_INTERRUPTED). Returns
        where the rover believes it stopped.

        The GNC's wait ends with E_DATA when nothing will drive the leg: no report leaves the
        leg's start within ``wait_timeout``, or the connection that started navigate closed and
        no pose came from anywhere for ``pose_settle`` after (a GNC that reconnects and goes on
        reporting keeps the job)."""
        from ..bus import tapped_call

        cfg, job, app = self.cfg, self.job, self.app
        settle = Settle(cfg.pose_settle, cfg.pose_still[0], cfg.pose_still[1], cfg.wait_timeout,
                        start=self.announced_at)
        gone: list[float] = []  # when this thread first saw the requester's connection closed

        def orphaned() -> bool:
            if not job.requester_gone.is_set():
                return False
            if not gone:
                gone.append(time.time())
            return time.time() - max(gone[0], app.pose.time) >= cfg.pose_settle

        try:
            return tapped_call(app.bus, self.rover.drive, pilot, settle=settle, since=since,
                               cancel=lambda: job.cancelled or orphaned())
        except Silent:
            x, y = self.announced_at[:2] if self.announced_at else (app.pose.x, app.pose.y)
            raise ProtocolError("E_DATA", f"the rover did not leave the leg's start ({x:.2f}, {y:.2f}) within "
                                          f"{cfg.wait_timeout:g} s (navigate.wait_timeout): the GNC drives the "
                                          f"waypoints to ({end[0]:.2f}, {end[1]:.2f}) reporting pose -x -y -heading "
                                          "as it goes, or sends pose -stopped true where the rover stands") from None
        except Exception as exc:
            if job.cancelled:
                raise Interrupted(f"{job.command} job {job.id} was interrupted") from None
            if isinstance(exc, DeviceInterrupted) and job.requester_gone.is_set():
                raise ProtocolError("E_DATA", f"the connection that started navigate closed and no pose came for "
                                              f"{cfg.pose_settle:g} s (navigate.pose_settle) while the leg to "
                                              f"({end[0]:.2f}, {end[1]:.2f}) waited: nothing drives it; start "
                                              "navigate again from the GNC's connection") from None
            raise

    # -- the legs ----------------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        try:
            return self._legs()
        finally:
            self.strategy.leave()

    def _legs(self) -> dict[str, Any]:
        app, cfg, goal, strategy = self.app, self.cfg, self.goal, self.strategy
        self.track.add((app.pose.x, app.pose.y, app.pose.heading))
        for _ in range(strategy.max_plans):
            self.job.check()
            leg = len(self.paths) + 1  # the leg being prepared: its scan, plan and drive carry its number
            pose = app.pose
            left = math.hypot(goal[0] - pose.x, goal[1] - pose.y)
            if left <= cfg.tolerance and strategy.arrived(left):
                break
            if strategy.drive_on(leg):
                continue
            if self.scans >= cfg.max_legs:
                break
            local = self.scan(leg)
            pose = app.pose
            if math.hypot(goal[0] - pose.x, goal[1] - pose.y) <= cfg.tolerance:
                break  # (a scan to check a dead-reckoned arrival, and it holds)
            strategy.scanned(leg, local)
        pose = app.pose
        if math.hypot(goal[0] - pose.x, goal[1] - pose.y) > cfg.tolerance:
            raise ProtocolError("E_DATA", f"goal not reached after {self.scans} scans and {len(self.paths)} legs; the "
                                          f"rover is at ({pose.x:.2f}, {pose.y:.2f}), "
                                          f"{math.hypot(goal[0] - pose.x, goal[1] - pose.y):.2f} m away")
        return self.products()

    def scan(self, leg: int) -> Any:
        """The leg's 360-degree DEM, matched by the localiser; returns its NavMaps. A second leg
        in a row that starts where the previous one did ends the job (no progress)."""
        from prox_workflows.algorithms.planner import NavMaps

        from ..scanning import run_dem

        app, cfg = self.app, self.cfg
        self.scans += 1
        pose = app.pose
        last = self.leg_starts[-1] if self.leg_starts else None
        if last is not None and math.hypot(pose.x - last[0], pose.y - last[1]) < cfg.min_progress:
            self.stalled += 1
            if self.stalled >= 2:
                raise ProtocolError("E_DATA", f"no progress: legs {leg - 2} to {leg} all started at ({pose.x:.2f}, "
                                              f"{pose.y:.2f}) (within {cfg.min_progress:g} m); the rover does not "
                                              "get along the waypoints, so a further scan from here would not help")
        else:
            self.stalled = 0
        self.leg_starts.append((pose.x, pose.y))
        dem_cfg = copy.deepcopy(app.config.get("dem_full_tof" if cfg.sensor == "tof" else "dem_full"))
        dem_cfg.range, dem_cfg.overlap, dem_cfg.name = list(cfg.range), cfg.overlap, f"{self.name}_leg{leg}"

        def progress(done: int, total: int, message: str, phase: str = "") -> None:
            self.progress(leg, done, total, message, phase)

        run_dem(self.job, dem_cfg, update=leg > 1 and not self.loc.active, sensor=cfg.sensor, progress=progress,
                out_dir="nav")
        self.loc.after_scan(self.job, leg)  # VO / map matching: corrects the pose and the leg's maps
        maps = app.maps.layers
        return NavMaps(maps["hazard"], maps["slope"], maps.geometry)

    def _ortho(self, maps: Any, path: np.ndarray, wps: np.ndarray, rover: tuple[float, float],
               size: float) -> tuple[np.ndarray, Any]:
        """The ortho-image the traverse is drawn on, and its grid. A mission that scanned nothing
        (the goal was within tolerance at the start) may have no map at all: the figure is then
        drawn on an unknown (NaN) ground that covers the rover, the goal and the track, so the OK
        line names a traverse figure as it always does."""
        from prox_workflows.grid import GridGeometry

        if maps is not None and "ortho" in maps:
            return maps["ortho"], maps.geometry
        xy = np.concatenate([np.asarray([rover, self.goal], dtype=np.float64), path.reshape(-1, 2),
                             wps.reshape(-1, 2), self.track.xy()])
        margin = size + 1.0  # m: the rover's outline and some ground round it
        lo, hi = xy.min(axis=0) - margin, xy.max(axis=0) + margin
        cell = max(float((hi - lo).max()) / 400.0, 0.01)  # a figure of about 400 cells a side
        geometry = GridGeometry.covering(float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]), cell)
        return np.full(geometry.shape, np.nan, dtype=np.float32), geometry

    def products(self) -> dict[str, Any]:
        """The traverse figure, the waypoints and the track; the OK line."""
        from prox_workflows.algorithms.planner import ortho_figure
        from prox_workflows.mapview import Marks
        from prox_workflows.products import write_png, write_text_atomic

        app, goal, job = self.app, self.goal, self.job
        pose = app.pose
        maps = app.maps.layers
        path = np.concatenate(self.paths) if self.paths else np.zeros((0, 2))
        wps = np.concatenate(self.waypoints) if self.waypoints else np.zeros((0, 2))
        traverse = app.data_path("nav", f"{self.name}_traverse.png")
        head = app.config.get("head")
        ortho, geometry = self._ortho(maps, path, wps, (pose.x, pose.y), max(head.rover_length, head.rover_width))
        write_png(traverse, ortho_figure(ortho, geometry, f"traverse to ({goal[0]:g}, {goal[1]:g})",
                                         Marks(rover=(pose.x, pose.y, pose.heading),
                                               rover_size=(head.rover_length, head.rover_width), path=path,
                                               waypoints=wps, track=self.track.xy(), goal=goal)))
        wfile = app.data_path("nav", f"{self.name}_waypoints.csv")
        write_text_atomic(wfile, "x,y,leg\n" + "".join(
            f"{x:.4f},{y:.4f},{i + 1}\n" for i, leg_wps in enumerate(self.waypoints) for x, y in leg_wps))
        tfile = self.track.write(app, self.name)
        return {"reached": True, "legs": len(self.paths), "path": app.rel(traverse), "waypoints": app.rel(wfile),
                "track": app.rel(tfile), "x": Fixed(pose.x, 3), "y": Fixed(pose.y, 3), **pose_fields(job),
                "loop": self.cfg.loop, **self.strategy.fields()}
