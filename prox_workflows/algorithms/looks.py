"""Where a standing look points the mast: the PTU positions whose frames show the ground the
next drive needs, beyond the ground no tilt shows.

A rover that images, then drives (MER's and Perseverance's ENav: stop, look, drive at most about
a metre within the ground the look judged, look again) needs the band its body sweeps over the
next drive seen before it moves, from beyond the mast's blind disc (the ground round the mast's
foot that even the PTU's lowest tilt leaves out) to the drive's far end. Two tilts cover it: the
lowest, whose view starts at the blind disc's edge and reaches about 1.5 m, and one further out
(-35 deg by default), whose view starts about a metre out and reaches past the next drive's end
(the next look's ground, judged before the rover reaches it); as many pans at each as the band's
bearings need (3-5 for a fan of drives ahead), and none at a tilt or pan whose frame shows only
ground the map has already judged.

Driving, the mast's gaze (:func:`gaze`) alternates between the path a little ahead, at the
lowest tilt, and farther along it; standing, a look at one point (:func:`look_at`) and a fan of
pans about a bearing (:func:`look_pans`) complete what the see loop asks of the mast. The device
calls (pointing the PTU, grabbing frames) are the driver's; here is only where to point.

Everything about the camera is asked of its owners: the field of view (the ToF's), the PTU's
lowest tilt (the PTU's limits), the mast's geometry (the head's calibration), the body (the
vehicle's); nothing here restates them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..grid import GridGeometry
from .rolling_map import path_poses
from .transforms import HeadCalibration, in_rover_frame

__all__ = ["View", "blind_disc", "blind_radius", "drive_band", "gaze", "look_at", "look_pans", "looked_from_here",
           "on_body", "round_look", "standing_look"]

BODY_MARGIN = 0.06  # m round the rover's box and wheels whose returns are its own
GAZE_NEAR, GAZE_FAR = 0.9, 1.8  # m along the path: where the near and the far frames of the gaze look
GAZE_PAN = 60.0  # deg: the gaze pans along the path at most this far off the heading
# within a hold of the gaze (navigate.see_gaze_hold frames) the mast pans again only where the
# path's bearing has moved more than GAZE_SLACK off the pan (a turn), well inside the ToF's field of view
GAZE_SLACK = 15.0  # deg
GAZE_STEP = 5.0  # deg: the gaze's pans are rounded to this (fewer moves)
LOOK_PAN = 150.0  # deg: a standing look at a point or a bearing pans at most this far off the heading
# a look from within this distance (m) and heading change (deg) of the last one is from the same place
SAME_PLACE, SAME_HEADING = 0.3, 20.0


@dataclass(frozen=True)
class View:
    """What a PTU-mounted camera shows: its field of view (deg), the PTU's lowest tilt and the
    farthest it pans either way (deg)."""

    fov_h: float
    fov_v: float
    lowest_tilt: float
    pan_limit: float = 180.0
    sensor: str = "tof"
    margin: float = 2.0  # deg inside the image's edge a point must lie to count as shown

    @classmethod
    def of_ptu(cls, limits: dict[str, dict[str, float]], fov_h: float, fov_v: float) -> View:
        """The view of a camera with that field of view (deg) on a PTU with those ``limits`` (as
        the PTU reports them: ``{"pan": {"min_deg", "max_deg"}, "tilt": {...}}``): its pan
        reach is the lesser side's, so a pan within it is reached either way."""
        pan = min(-float(limits["pan"]["min_deg"]), float(limits["pan"]["max_deg"]))
        return cls(fov_h, fov_v, float(limits["tilt"]["min_deg"]), pan)


def blind_radius(head: HeadCalibration, view: View) -> float:
    """The radius (m, on level ground round the pan axis's foot) of the ground no tilt shows: the
    lowest tilt's view starts there."""
    bz = head.ptu_base[2] + head.tilt_offset
    return bz / math.tan(math.radians(view.fov_v / 2 - view.lowest_tilt))


def blind_disc(pose: tuple[float, float, float], head: HeadCalibration, view: View) -> tuple[float, float, float]:
    """The ground round the mast's foot that no frame shows, even at the PTU's lowest tilt, for
    the rover at ``pose`` (x, y, heading deg): (x, y) of the pan axis's foot and the radius
    (:func:`blind_radius`)."""
    x, y, heading = pose
    bx, by, _ = head.ptu_base
    c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
    return x + bx * c - by * s, y + bx * s + by * c, blind_radius(head, view)


def gaze(frame: int, pose: tuple[float, float, float], remaining: np.ndarray, head: HeadCalibration,
         pan_tilt: tuple[float, float], tilts: tuple[float, float], hold: int) -> tuple[float, float] | None:
    """Where the ToF looks for the drive's ``frame``-th frame (counted from 1), the rover at
    ``pose`` with ``remaining`` waypoints ahead and the PTU at ``pan_tilt``; None: it stays.

    The mast pans along the path, not the heading, so the ground a turn will put under the
    wheels is seen before the turn; ``hold`` frames in turn it looks at the path
    ``GAZE_NEAR`` m ahead at the near tilt (``tilts[0]``: the PTU's lowest, where the next
    section is judged, closer, so with a third of the range noise) and at the point ``GAZE_FAR``
    m ahead at the far one (``tilts[1]``); pans are rounded to ``GAZE_STEP`` and kept within
    ``GAZE_PAN``, and within a hold the mast pans only where the path's bearing has moved
    ``GAZE_SLACK`` off its pan: a move longer than the cycle's motion holds the next frame."""
    near = (frame // hold) % 2 == 1
    ahead = path_poses(pose, remaining, GAZE_NEAR if near else GAZE_FAR, step=0.05)[-1]
    pan, _ = head.look_at(np.array([*in_rover_frame(pose, ahead[0], ahead[1]), 0.0]))
    pan = max(-GAZE_PAN, min(GAZE_PAN, round(pan / GAZE_STEP) * GAZE_STEP))
    tilt = tilts[0] if near else tilts[1]
    due = frame % hold == 0 or abs(pan - pan_tilt[0]) > GAZE_SLACK
    return (pan, tilt) if due and (pan, tilt) != pan_tilt else None


def looked_from_here(last: tuple[float, float, float] | None, pose: tuple[float, float, float]) -> bool:
    """Whether a look from ``pose`` would be one from about where the ``last`` look was taken
    (within ``SAME_PLACE`` and ``SAME_HEADING``): what that look did not show, another from the
    same place will not."""
    return last is not None and math.hypot(pose[0] - last[0], pose[1] - last[1]) < SAME_PLACE and \
        abs((pose[2] - last[2] + 180.0) % 360.0 - 180.0) < SAME_HEADING


def look_at(pose: tuple[float, float, float], x: float, y: float, head: HeadCalibration, lowest_tilt: float,
            far_tilt: float) -> tuple[float, float]:
    """The PTU position (pan, tilt deg) of a standing frame toward ground point (x, y): panned to
    it (within ``LOOK_PAN``), tilted to it but no lower than ``lowest_tilt`` and no higher than
    ``far_tilt``. The frame then shows the ground along that bearing from the mast's blind disc
    out (:func:`blind_disc`), which holds the point unless it lies inside that disc."""
    pan, tilt = head.look_at(np.array([*in_rover_frame(pose, x, y), 0.0]))
    return max(-LOOK_PAN, min(LOOK_PAN, pan)), max(lowest_tilt, min(far_tilt, tilt))


def look_pans(bearing: float, spread: float) -> list[float]:
    """The pans (deg) of a standing look toward ``bearing`` (deg from the heading) and ``spread``
    either side, each within ``LOOK_PAN``."""
    return [max(-LOOK_PAN, min(LOOK_PAN, pan)) for pan in (bearing - spread, bearing, bearing + spread)]


def round_look(pose: tuple[float, float, float], head: HeadCalibration, view: View, body: Any, drive: float,
               far_tilt: float, toward: float | None = None, bounds: Any = None,
               start_pan: float | None = None) -> list[tuple[float, float]]:
    """The PTU positions (:func:`standing_look`) of a standing look at ``pose`` that show the
    ground the ``body`` covers driving ``drive`` m in a fan of +-60 deg about ``toward`` (deg
    from the heading; None: all round, as a turn on the spot may face any way) and as far
    again, leaving out ground the ``bounds`` map (a :class:`~.bounds_map.BoundsMap`, if any)
    already holds within half the lower of the body's climb and clearance: wider bounds are
    what refuse a safe pose. ``start_pan``: where the mast points now (the serpentine's start)."""
    judged = None
    if bounds is not None:
        reach = 2 * drive + body.length
        lower, upper, g = bounds.window(pose[0] - reach, pose[1] - reach, pose[0] + reach, pose[1] + reach)
        with np.errstate(invalid="ignore"):
            judged = (upper - lower <= min(body.climb, body.clearance) / 2, g)
    fan = np.arange(-60.0, 60.1, 15.0) + toward if toward is not None else np.arange(-180.0, 180.0, 15.0)
    return standing_look(pose, head, view, body.length, body.width, drive, bearings=fan, far_tilt=far_tilt,
                         judged=judged, start_pan=start_pan)


def on_body(points: np.ndarray, body: Any, margin: float = BODY_MARGIN) -> np.ndarray:
    """Rover-frame points on the rover itself (its box and wheels, ``margin`` grown): the mast
    looking down and back sees its own deck and wheels, which are not ground."""
    half_x = max(body.length / 2, body.wheelbase / 2 + body.wheel_radius) + margin
    half_y = max(body.width / 2, body.track / 2 + body.wheel_width / 2) + margin
    return (np.abs(points[:, 0]) <= half_x) & (np.abs(points[:, 1]) <= half_y)


def drive_band(pose: tuple[float, float, float], length: float, width: float, distance: float,
               bearings: np.ndarray | list[float], step: float = 0.05) -> np.ndarray:
    """Global (x, y) samples, ``step`` apart, of the ground the body (``length`` x ``width``)
    covers turning on the spot at ``pose`` (x, y, heading deg) to each of ``bearings`` (deg from
    the heading) and driving ``distance`` straight on along it."""
    along = np.arange(-length / 2, length / 2 + 1e-9, step)
    across = np.arange(-width / 2, width / 2 + 1e-9, step)
    bx, by = (a.ravel() for a in np.meshgrid(along, across))
    out = []
    for b in np.atleast_1d(np.asarray(bearings, dtype=np.float64)):
        h = math.radians(pose[2] + b)
        c, s = math.cos(h), math.sin(h)
        for d in np.arange(0.0, distance + 1e-9, step):
            out.append(np.column_stack([pose[0] + (bx + d) * c - by * s, pose[1] + (bx + d) * s + by * c]))
    if not out:
        return np.zeros((0, 2))
    pts = np.concatenate(out)
    # samples of one step's grid once each
    keys = np.unique(np.round(pts / step).astype(np.int64), axis=0)
    return keys.astype(np.float64) * step


def _shown(head: HeadCalibration, view: View, pan: float, tilt: float, rover_pts: np.ndarray) -> np.ndarray:
    """Which rover-frame points (N x 3) a frame at (pan, tilt) shows: in front of the camera and
    within its field of view, ``margin`` inside the edges."""
    T = head.T_rover_from_sensor(view.sensor, pan, tilt)
    cam = (rover_pts - T[:3, 3]) @ T[:3, :3]  # optical frame: x right, y down, z forward
    z = cam[:, 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        ax = np.degrees(np.arctan2(np.abs(cam[:, 0]), z))
        ay = np.degrees(np.arctan2(np.abs(cam[:, 1]), z))
    return (z > 0) & (ax <= view.fov_h / 2 - view.margin) & (ay <= view.fov_v / 2 - view.margin)


def standing_look(pose: tuple[float, float, float], head: HeadCalibration, view: View, length: float,
                  width: float, distance: float = 1.0, beyond: float | None = None,
                  bearings: np.ndarray | list[float] | None = None,
                  tilts: tuple[float, ...] | None = None, far_tilt: float = -35.0, ground: float = 0.0,
                  judged: tuple[np.ndarray, GridGeometry] | None = None, overlap: float = 0.15,
                  start_pan: float | None = None) -> list[tuple[float, float]]:
    """PTU positions (pan, tilt deg) for a standing look at ``pose`` that shows the ground the
    body covers over the next drive (:func:`drive_band`: at most ``distance`` m along each of
    ``bearings``, deg from the heading; default a fan of -60..60 deg) and the ``beyond`` m after
    it (default another ``distance``: the next drive's ground, judged before the rover reaches
    it, so that it drives on after the next look without waiting for it), outside the blind disc
    (:func:`blind_radius`), at each of ``tilts`` (default the lowest and ``far_tilt``).

    ``ground`` is the ground's height under the rover's wheels (m, rover frame: 0 on level
    ground); ``judged`` a boolean grid of cells the map has already judged (bounded) and its
    geometry: ground there needs no frame. At each tilt the band's points that tilt shows when
    panned to them (and that an earlier tilt's frames do not) are covered by pans ``fov_h (1 -
    overlap)`` apart, centred on the span of their bearings (3-5 for the default fan; a ring all
    round takes 9-10), within the PTU's ``pan_limit``; a pan whose frame would show none of them
    is left out. Ordered as a serpentine (the lowest tilt one way, the next the other), so the PTU
    travels least, from the end of the first tilt's pans nearer ``start_pan`` (where the mast
    points now; None: the lowest pan): the PTU's moves awaited took a fifth of dense 5's time,
    and a look begun at the far end slews across the whole fan first."""
    if bearings is None:
        bearings = np.arange(-60.0, 60.0 + 1e-9, 15.0)
    if tilts is None:
        tilts = (view.lowest_tilt, max(view.lowest_tilt, far_tilt))
    band = drive_band(pose, length, width, distance + (distance if beyond is None else beyond), bearings)
    c, s = math.cos(math.radians(pose[2])), math.sin(math.radians(pose[2]))
    dx, dy = band[:, 0] - pose[0], band[:, 1] - pose[1]
    rover = np.column_stack([c * dx + s * dy, -s * dx + c * dy, np.full(len(band), ground)])
    foot = np.hypot(rover[:, 0] - head.ptu_base[0], rover[:, 1] - head.ptu_base[1])
    # the ground under the body as it stands is the body's own (its wheels and attitude say it), and
    # the mast sees its deck there, not the ground
    under = (np.abs(rover[:, 0]) <= length / 2) & (np.abs(rover[:, 1]) <= width / 2)
    need = (foot > blind_radius(head, view)) & ~under
    if judged is not None:
        done, g = judged
        r, col = g.cell_of(band[:, 0], band[:, 1])
        inside = g.inside(r, col)
        seen = np.zeros(len(band), bool)
        seen[inside] = np.asarray(done)[r[inside], col[inside]]
        need &= ~seen
    pts = rover[need]
    if not len(pts):
        return []
    base = np.array(head.ptu_base) + np.array([0.0, 0.0, head.tilt_offset])
    azimuth = np.degrees(np.arctan2(pts[:, 1] - base[1], pts[:, 0] - base[0]))
    step = view.fov_h * (1.0 - overlap)
    rows: list[list[tuple[float, float]]] = []  # per tilt that shows any, its pans from the lowest
    left = set(range(len(pts)))
    for tilt in tilts:
        # the points this tilt shows when panned straight at them, not shown by an earlier tilt's frames
        todo = np.array(sorted(left), dtype=np.int64)
        if not len(todo):
            break
        # panned straight at a point is the point turned about the pan axis onto the heading, at pan 0
        a = np.radians(azimuth[todo])
        px, py = pts[todo, 0] - head.ptu_base[0], pts[todo, 1] - head.ptu_base[1]
        ahead = np.column_stack([head.ptu_base[0] + np.cos(a) * px + np.sin(a) * py,
                                 head.ptu_base[1] - np.sin(a) * px + np.cos(a) * py, pts[todo, 2]])
        own = _shown(head, view, 0.0, tilt, ahead)
        todo = todo[own]
        if not len(todo):
            continue
        # bearings about the PTU's zero, where its pan range is centred: a band behind the rover
        # spans +-180 deg, and is panned to from either end of the range
        lo, hi = float(azimuth[todo].min()), float(azimuth[todo].max())
        count = max(1, int(math.ceil((hi - lo) / step + 1e-9)))
        pans = (lo + hi) / 2 + (np.arange(count) - (count - 1) / 2) * step
        chosen = []
        for pan in np.clip(pans, -view.pan_limit, view.pan_limit):
            shown = _shown(head, view, float(pan), tilt, pts[todo])
            if shown.any():
                chosen.append((round(float(pan), 1), float(tilt)))
                left -= set(todo[shown].tolist())
        if chosen:
            rows.append(chosen)
    flip = bool(rows) and start_pan is not None and abs(rows[0][-1][0] - start_pan) < abs(rows[0][0][0] - start_pan)
    return [p for i, row in enumerate(rows) for p in (row if (i % 2 == 0) != flip else row[::-1])]
