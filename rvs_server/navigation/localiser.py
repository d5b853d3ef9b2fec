"""Knowing where the rover is during navigate: the pose estimate between legs.

Dead reckoning alone (the wheels' odometry after an ``-auto`` leg) drifts with every metre: with
5 % slip and 2 degrees of heading drift per metre the rover ends metres from where it believes it
is after a few legs, and a goal "reached" in its belief is not reached on the ground. Each leg
starts with a 360-degree DEM made around the rover; that DEM is placed with the believed pose,
so any pose error shows as the DEM being shifted and turned against the terrain it shows. Two
references can measure that:

- ``vo``: the previous leg's DEM (placed with the previous, already corrected, pose). The two
  scans share most of their ground, at centimetre detail (rocks, roughness), so the match is
  sharp; it is relative, so its errors add up leg by leg, slowly (surface-based visual odometry
  from the leg's own ToF or stereo DEM).
- ``map``: the global DEM from orbit (``navigate -global FILE`` or ``dem.tif`` in
  ``navigate.global_maps``). Coarser (a metre a cell), but absolute: the error it leaves does not
  grow with the distance driven.

``both`` applies VO and then the map, fusing their positions by their sigmas. The correction
moves the pose (source ``vo`` or ``map``, with the match's sigma), the rover's own estimate (the
simulated rover's odometry takes it; a real GNC gets it by the ``localised`` EVENT) and the leg's maps
(resampled onto the corrected placement, so the plan made on them agrees with the pose). A
match that cannot tell (flat ground, too little seen, best match at the window's edge) leaves
the dead-reckoned pose and says so.

Navigate calls :meth:`Localiser.after_drive` once a leg is driven and :meth:`Localiser.after_scan`
once the next leg's DEM is made; everything else lives here and in
``prox_workflows.algorithms.map_match``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from prox_workflows.algorithms.map_match import MatchResult, match_dem, overlay_layers, transform_layers
from prox_workflows.grid import Layers

from ..protocol import Fixed, Reply

if TYPE_CHECKING:
    from prox_workflows.algorithms.global_map import GlobalMap

    from ..jobs import Job
    from .config import LocaliseConfig

MODES = ("none", "vo", "map", "both")


@dataclass
class Localiser:
    """One navigate job's pose estimation: its mode, the global DEM, the last leg's DEM and the
    sigma the dead reckoning has added since the last fix (which sets the next search window)."""

    mode: str
    reference: GlobalMap | None = None
    drift: float = 0.05  # share of the distance driven the position may be off by (1 sigma)
    heading_drift: float = 2.0  # deg per metre driven (1 sigma)
    rover: Any = None  # the rover device (drivers.rover): a fix goes to its own estimate too
    previous: Layers | None = None  # the maps of the legs so far, on their corrected placements
    sigma: float = 0.0  # the estimate's position sigma (m): the pose set from odometry does not carry it
    sigma_heading: float = 0.0  # deg
    grown: float = 0.0  # position sigma added by dead reckoning since the last fix (m)
    grown_heading: float = 0.0  # deg
    fixes: list[dict[str, Any]] = field(default_factory=list)

    @classmethod
    def configured(cls, cfg: LocaliseConfig, reference: GlobalMap | None, rover: Any) -> Localiser:
        """The localiser navigate's ``localisation`` section asks for."""
        return cls(cfg.localise, reference, cfg.drift, cfg.heading_drift, rover)

    @property
    def active(self) -> bool:
        """Whether each leg's DEM is matched. The leg's DEM is then made alone (a DEM fused with
        the earlier legs' while placed by a drifted pose would blur the very shift the match
        measures), matched, moved, and laid over the earlier legs' maps here."""
        return self.mode != "none"

    @property
    def uses_map(self) -> bool:
        return self.mode in ("map", "both") and self.reference is not None and self.reference.dem is not None

    def wants_fix(self, pose: Any) -> bool:
        """A goal reached on dead reckoning alone is checked by one more scan and match before
        navigate believes it (the last leg's drift is as large as any other's)."""
        return self.active and pose.source == "odometry" and self.grown > 0.0

    def after_drive(self, job: Job, waypoints: np.ndarray) -> float:
        """The pose just set from dead reckoning along ``waypoints`` (or the track driven): its
        sigma grows with the distance, which is returned."""
        xy = np.asarray(waypoints, dtype=float).reshape(-1, 2)  # k x 2: the waypoints or the track driven
        dist = float(np.hypot(*np.diff(xy, axis=0).T).sum()) if len(xy) > 1 else 0.0
        app = job.app
        p = app.pose
        if p.source != "odometry":
            return dist  # a GNC's pose carries its own accuracy
        dh = self.heading_drift * dist
        # lateral error of a heading error that grew linearly along the leg: half of it at the end
        dxy = self.drift * dist + math.radians(self.sigma_heading + dh / 2.0) * dist
        self.grown += dxy
        self.grown_heading += dh
        self.sigma += dxy
        self.sigma_heading += dh
        app.set_pose(p.x, p.y, p.heading, source="odometry", sigma=self.sigma, sigma_heading=self.sigma_heading)
        return dist

    def after_scan(self, job: Job, leg: int) -> None:
        """Match the leg's fresh DEM (the current maps) and correct the pose and the maps."""
        if not self.active:
            return
        app = job.app
        layers = app.maps.layers
        if layers is None or "dem" not in layers:
            return
        p = app.pose
        x, y, h, sigma, sigma_h, source = p.x, p.y, p.heading, self.sigma, self.sigma_heading, p.source
        moved = layers
        # 2 sigma of what dead reckoning added: the matcher uses only ground both DEMs show under
        # every motion searched, so a wider window costs overlap (and a 3-sigma miss leaves the
        # dead-reckoned pose, no worse than without VO)
        window_xy = min(max(2.0 * self.grown + 0.15, 0.3), 2.0)
        window_yaw = min(max(2.0 * self.grown_heading + 1.5, 3.0), 12.0)
        changed = False
        if self.mode in ("vo", "both") and self.previous is not None and "dem" in self.previous:
            prev = self.previous
            m = match_dem(moved["dem"], moved.geometry, prev["dem"], prev.geometry, (x, y),
                          search_xy=window_xy, search_yaw=window_yaw, sample=0.15, step_xy=0.1,
                          step_yaw=1.0, radius=4.5, max_sigma_xy=0.2)
            self._report(job, leg, "vo", m)
            if m.ok:
                moved = transform_layers(moved, (x, y), m.dx, m.dy, m.dyaw)
                base = sigma - self.grown  # the sigma at the last fix
                base_h = sigma_h - self.grown_heading
                x, y, h = x + m.dx, y + m.dy, h + m.dyaw
                sigma = math.hypot(max(base, 0.0), m.sigma_xy)
                sigma_h = math.hypot(max(base_h, 0.0), m.sigma_yaw)
                source, changed = "vo", True
        if self.uses_map:
            fix = self._map_fix(job, leg, moved["dem"], moved.geometry, (x, y), sigma, sigma_h, source)
            if fix is not None:
                dx, dy, dyaw, sigma, sigma_h = fix
                moved = transform_layers(moved, (x, y), dx, dy, dyaw)
                x, y, h = x + dx, y + dy, h + dyaw
                source, changed = "map", True
        if changed:
            self._take(app, x, y, h, source, sigma, sigma_h)
        merged = overlay_layers(self.previous, moved)
        app.maps.replace(merged, app.maps.name or "", app.maps.files())
        self.previous = merged

    def while_seeing(self, job: Job, leg: int, dem: np.ndarray, geometry: Any,
                     standing: bool = False) -> tuple[float, float, float] | None:
        """The see loop's fix between its replans (its 360-degree scans are matched by
        :meth:`after_scan`): the rolling map's DEM, placed frame by frame with the dead-reckoned
        pose, matched on the global DEM. Returns the correction (dx, dy, dyaw about the believed
        position) for the caller to move its rolling map by, or None when the match cannot tell.
        ``standing``: the frames were all taken at the present pose (a look round on arrival)."""
        if not self.uses_map:
            return None
        p = job.app.pose
        # frames placed while driving carry errors from the last fix's (about 0) to today's: the
        # match lands between, so half of what dead reckoning added stays in the fix's sigma;
        # frames taken standing share one pose error, which the match measures whole
        blur = (0.0, 0.0) if standing else (self.grown / 2.0, self.grown_heading / 2.0)
        fix = self._map_fix(job, leg, dem, geometry, (p.x, p.y), self.sigma, self.sigma_heading, p.source,
                            blur=blur)
        if fix is None:
            return None
        dx, dy, dyaw, sigma, sigma_h = fix
        self._take(job.app, p.x + dx, p.y + dy, p.heading + dyaw, "map", sigma, sigma_h)
        return dx, dy, dyaw

    def _map_fix(self, job: Job, leg: int, dem: np.ndarray, geometry: Any, at: tuple[float, float], sigma: float,
                 sigma_h: float, source: str, blur: tuple[float, float] = (0.0, 0.0)
                 ) -> tuple[float, float, float, float, float] | None:
        """``dem`` (placed with the pose at ``at``, of these sigmas) matched on the global DEM and
        fused with that estimate: (dx, dy, dyaw, sigma, sigma_heading), or None. ``blur`` (m,
        deg) is added to the match's sigmas: what the DEM's own placement is off by, beyond what
        the heights show (a rolling map's frames were placed along a drifting pose)."""
        assert self.reference is not None and self.reference.dem is not None
        ref = self.reference
        m = match_dem(dem, geometry, ref.dem, ref.geometry, at, search_xy=min(max(3.0 * sigma + 0.3, 0.6), 3.0),
                      search_yaw=min(max(3.0 * sigma_h + 2.0, 3.0), 15.0), radius=4.5)
        self._report(job, leg, "map", m)
        # a GNC's pose says nothing of its accuracy: the map decides; a pose given with sigma 0
        # otherwise (the start) is exact, the frame is defined by it
        prior, prior_h = (math.inf, math.inf) if source == "gnc" else (sigma, sigma_h)
        if not (m.ok and prior > 0):
            return None
        s_xy, s_yaw = math.hypot(m.sigma_xy, blur[0]), math.hypot(m.sigma_yaw, blur[1])
        # inverse-variance fusion with what we had (dead reckoning or VO)
        w = 1.0 if math.isinf(prior) else prior ** 2 / (prior ** 2 + s_xy ** 2)
        wh = 1.0 if math.isinf(prior_h) else prior_h ** 2 / (prior_h ** 2 + s_yaw ** 2)
        sigma = math.sqrt(1.0 / (1.0 / prior ** 2 + 1.0 / max(s_xy, 1e-6) ** 2))
        sigma_h = math.sqrt(1.0 / (1.0 / max(prior_h, 1e-6) ** 2 + 1.0 / max(s_yaw, 1e-6) ** 2))
        return w * m.dx, w * m.dy, wh * m.dyaw, sigma, sigma_h

    def _take(self, app: Any, x: float, y: float, h: float, source: str, sigma: float, sigma_h: float) -> None:
        """A fix becomes the pose, and the rover's own estimate takes it."""
        h = (h + 180.0) % 360.0 - 180.0
        app.set_pose(x, y, h, source=source, sigma=sigma, sigma_heading=sigma_h)
        if self.rover is not None:
            self.rover.take_fix((x, y, h))
        self.grown = self.grown_heading = 0.0
        self.sigma, self.sigma_heading = sigma, sigma_h

    def _report(self, job: Job, leg: int, method: str, m: MatchResult) -> None:
        """One EVENT per match, taken or not: a GNC may apply the fix to its own estimate."""
        app = job.app
        fix = {"leg": leg, "method": method, "ok": m.ok, "dx": m.dx, "dy": m.dy, "dyaw": m.dyaw,
               "sigma": m.sigma_xy, "sigma_yaw": m.sigma_yaw, "rms": m.rms, "ms": m.seconds * 1000.0,
               "reason": m.reason}
        self.fixes.append(fix)
        fields: dict[str, Any] = {"kind": "localised", "job": job.id, "leg": leg, "method": method, "found": m.ok,
                                  "match_dx": Fixed(m.dx, 3), "match_dy": Fixed(m.dy, 3),
                                  "match_dyaw": Fixed(m.dyaw, 2), "match_ms": Fixed(m.seconds * 1000.0, 0)}
        if math.isfinite(m.rms):
            fields["match_rms"] = Fixed(m.rms, 3)
        if math.isfinite(m.sigma_xy):
            fields["pose_sigma"] = Fixed(m.sigma_xy, 3)
        if not m.ok:
            fields["message"] = m.reason
        app.broadcast_threadsafe(Reply("RVS", "EVENT", fields))
        job.progress(1, 1, f"{method} match: {'correction' if m.ok else 'not taken'} dx={m.dx:+.3f} dy={m.dy:+.3f} "
                           f"dyaw={m.dyaw:+.2f} sigma={m.sigma_xy:.3f} m"
                           + ("" if m.ok else f" ({m.reason})"), phase=f"localise-{method}", leg=leg)


def pose_fields(job: Job) -> dict[str, Any]:
    """pose_source and pose_sigma, for a leg's EVENT and navigate's OK line."""
    p = job.app.pose
    return {"pose_source": p.source, "pose_sigma": Fixed(p.sigma, 3), "pose_sigma_heading": Fixed(p.sigma_heading, 2)}
