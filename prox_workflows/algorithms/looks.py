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
from .transforms import HeadCalibration

__all__ = ["View", "blind_radius", "drive_band", "on_body", "standing_look"]

BODY_MARGIN = 0.06  # m round the rover's box and wheels whose returns are its own


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


def blind_radius(head: HeadCalibration, view: View) -> float:
    """The radius (m, on level ground round the pan axis's foot) of the ground no tilt shows: the
    lowest tilt's view starts there."""
    bz = head.ptu_base[2] + head.tilt_offset
    return bz / math.tan(math.radians(view.fov_v / 2 - view.lowest_tilt))


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
                  judged: tuple[np.ndarray, GridGeometry] | None = None, overlap: float = 0.15
                  ) -> list[tuple[float, float]]:
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
    is left out. Ordered as a serpentine (the lowest tilt left to right, the next right to left),
    so the PTU travels least."""
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
    out: list[tuple[float, float]] = []
    left = set(range(len(pts)))
    for i, tilt in enumerate(tilts):
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
        out.extend(chosen if i % 2 == 0 else chosen[::-1])
    return out
