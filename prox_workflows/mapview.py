"""Map layers as pictures for people: the console's map images and the preview PNGs beside the
products, drawn by one renderer so both look the same.

:func:`layer_rgba` colours a layer with undefined cells transparent (the console draws it over
its own grid; never black, which reads as "safe" on a thesis-style hazard map). :func:`figure`
makes the operator-ready PNG: the layer over a hatched "unseen" background, axes in metres, a
scale bar, a north arrow, the rover's footprint with its forward arrow, path, waypoints and track
when given, and a legend that says exactly what the colours and marks are.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from rvs_params.hazard import HAZARDOUS, SAFE

from .colormaps import colorize
from .grid import GridGeometry

Colour = tuple[int, int, int]

SAFE_RGBA = (60, 170, 80, 60)  # light: the ground under it stays readable
HAZARD_RGBA = (220, 40, 40, 230)
PATH: Colour = (20, 150, 60)
WAYPOINT: Colour = (30, 90, 220)
TRACK: Colour = (30, 110, 240)
ROVER: Colour = (30, 40, 50)
ARROW: Colour = (255, 190, 40)
GOAL: Colour = (200, 30, 30)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


@dataclass(frozen=True)
class Style:
    """How a layer is coloured: ``kind`` continuous (a colour map over lo..hi, default the 1st..
    99th percentile), classes (the hazard map's codes), grey (the ortho-image) or shaded
    (continuous over a hillshade: the DEM)."""

    kind: str = "continuous"
    colormap: int | np.ndarray = cv2.COLORMAP_VIRIDIS
    lo: float | None = None
    hi: float | None = None
    unit: str = ""
    marks: tuple[tuple[float, str], ...] = ()  # values marked on the colour ramp (a threshold)


def _lut(colormap: int | np.ndarray) -> np.ndarray:
    """256 RGB colours of an OpenCV colormap id or a 256 x 1 x 3 BGR LUT."""
    ramp = np.arange(256, dtype=np.uint8).reshape(256, 1)
    bgr = cv2.applyColorMap(ramp, colormap) if isinstance(colormap, int) else cv2.LUT(
        cv2.cvtColor(ramp, cv2.COLOR_GRAY2BGR), colormap)
    return bgr.reshape(256, 3)[:, ::-1]


def percentile_range(values: np.ndarray) -> tuple[float | None, float | None]:
    """1st..99th percentile from at most ~250,000 cells: a map's colour range does not need every
    cell, and a full percentile is a third of the render of a 2000 x 2000 layer."""
    sample = values[:: max(1, values.shape[0] // 500), :: max(1, values.shape[1] // 500)]
    finite = sample[np.isfinite(sample)]
    if finite.size == 0:
        return None, None
    lo, hi = np.percentile(finite, [1, 99])
    return float(lo), float(hi)


def hillshade(dem: np.ndarray, cell: float) -> np.ndarray:
    """Shaded relief, light from the north-west at 45 degrees (the cartographers' convention).

    The surface normal dotted with the light, in float32 without trigonometry per cell: the
    arctan/cos form costs a second on a 2000 x 2000 layer, this a tenth of it."""
    finite = np.isfinite(dem)
    z = np.where(finite, dem, np.nanmean(dem) if finite.any() else 0.0).astype(np.float32)
    gx = np.zeros_like(z)
    gy = np.zeros_like(z)
    gx[:, 1:-1] = (z[:, 2:] - z[:, :-2]) / (2 * cell)  # east
    gy[1:-1, :] = (z[:-2, :] - z[2:, :]) / (2 * cell)  # north: row 0 is the northern edge
    alt, az = math.radians(45.0), math.radians(315.0)  # azimuth clockwise from north
    lx, ly, lz = math.cos(alt) * math.sin(az), math.cos(alt) * math.cos(az), math.sin(alt)
    return np.clip((lz - gx * lx - gy * ly) / np.sqrt(1.0 + gx * gx + gy * gy), 0.0, 1.0)


def layer_rgba(values: np.ndarray, style: Style, cell: float = 1.0) -> tuple[np.ndarray, dict[str, Any]]:
    """RGBA uint8 of a layer and its legend (JSON-ready); undefined cells transparent."""
    if values.ndim == 3:  # an RGB image
        rgb = values[..., :3].astype(np.uint8)
        return np.dstack([rgb, np.where(rgb.any(axis=2), 255, 0).astype(np.uint8)]), {"kind": "image"}
    defined = np.isfinite(values) if values.dtype.kind == "f" else np.ones(values.shape, bool)
    rgba = np.zeros(values.shape + (4,), np.uint8)
    if style.kind == "classes":
        rgba[values == SAFE] = SAFE_RGBA
        rgba[values == HAZARDOUS] = HAZARD_RGBA
        # colours as drawn: RGBA (alpha 0: transparent, shown hatched)
        return rgba, {"kind": "classes", "entries": [[list(SAFE_RGBA), "safe"], [list(HAZARD_RGBA), "hazardous"],
                                                      [[0, 0, 0, 0], "undefined"]]}
    if style.kind == "grey":
        grey = np.nan_to_num(values.astype(np.float32))
        if values.dtype != np.uint8:
            seen = defined & (grey > 0)
            top = float(np.percentile(grey[seen], 99.5)) if seen.any() else 1.0
            grey = np.clip(grey / max(top, 1e-9) * 255.0, 0, 255)
        rgba[..., :3] = grey[..., None].astype(np.uint8)
        rgba[..., 3] = np.where(defined & (grey > 0), 255, 0)  # 0 is "unseen" in an ortho-image
        return rgba, {"kind": "image", "unit": style.unit}
    data = values.astype(np.float32)
    lo, hi = style.lo, style.hi
    if lo is None or hi is None:
        plo, phi = percentile_range(data)
        lo = plo if lo is None else lo
        hi = phi if hi is None else hi
    colour, lo, hi = colorize(data, lo, hi, colormap=style.colormap)
    if style.kind == "shaded":
        colour = (colour.astype(np.float32) * (0.35 + 0.65 * hillshade(data, cell)[..., None])).astype(np.uint8)
    rgba[..., :3] = colour
    rgba[..., 3] = np.where(defined, 255, 0)
    stops = _lut(style.colormap)[np.linspace(0, 255, 6).astype(int)]
    return rgba, {"kind": "ramp", "colours": stops.tolist(), "lo": lo, "hi": hi, "unit": style.unit,
                  "marks": [[v, label] for v, label in style.marks]}


# ------------------------------------------------------------------------------ the figure


def nice_step(raw: float) -> float:
    p = 10.0 ** math.floor(math.log10(raw))
    for m in (1, 2, 5, 10):
        if m * p >= raw:
            return m * p
    return 10 * p


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float = 0.42, colour: Colour = (20, 20, 20),
          thick: int = 1) -> None:
    cv2.putText(img, text, org, _FONT, scale, colour, thick, cv2.LINE_AA)


def _hatch(h: int, w: int) -> np.ndarray:
    """White with light grey diagonals: "nobody has seen this ground", unlike any layer colour."""
    yy, xx = np.mgrid[0:h, 0:w]
    out = np.full((h, w, 3), 255, np.uint8)
    out[((xx + yy) % 10) < 2] = (205, 205, 205)
    return out


@dataclass(frozen=True)
class Marks:
    """What is drawn over the layer, in the map's metres."""

    rover: tuple[float, float, float] | None = None  # x, y, heading (deg)
    rover_size: tuple[float, float] = (0.51, 0.40)  # length, width
    path: np.ndarray | None = None  # (N, 2) A* path
    driven: int | None = None  # the path's first `driven` points are what the rover drives
    waypoints: np.ndarray | None = None  # (M, 2)
    track: np.ndarray | None = None  # (K, 2) where the rover went
    goal: tuple[float, float] | None = None


def figure(rgba: np.ndarray, geometry: GridGeometry, legend: dict[str, Any], title: str,
           marks: Marks | None = None, min_side: int = 480, max_side: int = 1400) -> np.ndarray:
    """The operator-ready RGB picture of one layer (see the module's docstring)."""
    marks = marks or Marks()
    h, w = rgba.shape[:2]
    scale = max(min_side / max(h, w), 1.0)
    scale = min(scale, max_side / max(h, w)) if max(h, w) * scale > max_side else scale
    mw, mh = max(1, round(w * scale)), max(1, round(h * scale))
    interp = cv2.INTER_NEAREST if scale >= 1 else cv2.INTER_AREA
    layer = cv2.resize(rgba, (mw, mh), interpolation=interp).astype(np.float32)
    alpha = layer[..., 3:4] / 255.0
    mapimg = (layer[..., :3] * alpha + _hatch(mh, mw) * (1 - alpha)).astype(np.uint8)
    px_per_m = mw / (geometry.width * geometry.cell)

    def px(xy: Any) -> np.ndarray:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        col = (xy[:, 0] - geometry.xmin) * px_per_m
        row = (geometry.ymax - xy[:, 1]) * px_per_m
        return np.round(np.stack([col, row], axis=1) * 16).astype(np.int32)  # 4 bits of sub-pixel

    aa = cv2.LINE_AA
    if marks.track is not None and len(marks.track) > 1:
        cv2.polylines(mapimg, [px(marks.track)], False, TRACK, 2, aa, shift=4)
    if marks.path is not None and len(marks.path) > 1:
        cut = len(marks.path) if marks.driven is None else marks.driven
        if cut < len(marks.path):
            cv2.polylines(mapimg, [px(marks.path[max(cut - 1, 0):])], False, (140, 200, 150), 2, aa, shift=4)
        cv2.polylines(mapimg, [px(marks.path[:cut])], False, PATH, 3, aa, shift=4)
    if marks.waypoints is not None and len(marks.waypoints):
        for p in px(marks.waypoints):
            cv2.circle(mapimg, (int(p[0]), int(p[1])), 5 * 16, WAYPOINT, -1, aa, shift=4)
            cv2.circle(mapimg, (int(p[0]), int(p[1])), 5 * 16, (255, 255, 255), 1, aa, shift=4)
    if marks.goal is not None:
        gx, gy = (int(v) for v in px(marks.goal)[0])
        d = 7 * 16
        cv2.line(mapimg, (gx - d, gy - d), (gx + d, gy + d), GOAL, 3, aa, shift=4)
        cv2.line(mapimg, (gx - d, gy + d), (gx + d, gy - d), GOAL, 3, aa, shift=4)
    if marks.rover is not None:
        x, y, heading = marks.rover
        c, s = math.cos(math.radians(heading)), math.sin(math.radians(heading))
        half_l, half_w = marks.rover_size[0] / 2, marks.rover_size[1] / 2
        corners = [(x + c * a - s * b, y + s * a + c * b) for a, b in
                   ((half_l, half_w), (-half_l, half_w), (-half_l, -half_w), (half_l, -half_w))]
        poly = px(corners)
        cv2.fillPoly(mapimg, [poly], ROVER, aa, shift=4)
        cv2.polylines(mapimg, [poly], True, (255, 255, 255), 1, aa, shift=4)
        tip = max(half_l + 0.25, 28 / px_per_m)  # the forward arrow reaches past the body
        start, end = px([(x, y)])[0], px([(x + c * tip, y + s * tip)])[0]
        cv2.arrowedLine(mapimg, (int(start[0]), int(start[1])), (int(end[0]), int(end[1])), ARROW, 3, aa,
                        shift=4, tipLength=0.35)

    # scale bar (bottom left, inside the map) and north arrow (top right)
    metres = nice_step(100 / px_per_m)
    bar = int(round(metres * px_per_m))
    x0, y0 = 10, mh - 12
    cv2.rectangle(mapimg, (x0 - 5, y0 - 18), (x0 + bar + 52, y0 + 6), (255, 255, 255), -1)
    cv2.line(mapimg, (x0, y0), (x0 + bar, y0), (0, 0, 0), 2)
    for xb in (x0, x0 + bar):
        cv2.line(mapimg, (xb, y0 - 5), (xb, y0), (0, 0, 0), 2)
    _text(mapimg, f"{metres:g} m", (x0 + bar + 5, y0 + 4))
    nx, ny = mw - 22, 34
    cv2.fillPoly(mapimg, [np.array([[nx, ny - 24], [nx - 8, ny], [nx + 8, ny]], np.int32)], (0, 0, 0), aa)
    _text(mapimg, "+y", (nx - 9, ny + 16))

    # frame: title above, axes in metres left and below, legend panel right
    left, top, bottom, panel = 64, 34, 40, 230
    out = np.full((top + mh + bottom, left + mw + panel, 3), 255, np.uint8)
    out[top:top + mh, left:left + mw] = mapimg
    cv2.rectangle(out, (left - 1, top - 1), (left + mw, top + mh), (60, 60, 60), 1)
    _text(out, title, (left, 22), 0.55, thick=1)
    step = nice_step(80 / px_per_m)
    for xv in np.arange(math.ceil(geometry.xmin / step) * step, geometry.xmax + 1e-9, step):
        c = left + int(round((xv - geometry.xmin) * px_per_m))
        cv2.line(out, (c, top + mh), (c, top + mh + 5), (60, 60, 60), 1)
        label = f"{xv:g}"
        _text(out, label, (c - 4 * len(label), top + mh + 18), 0.38)
    _text(out, "x (m)", (left + mw // 2 - 15, top + mh + 34), 0.4)
    for yv in np.arange(math.ceil(geometry.ymin / step) * step, geometry.ymax + 1e-9, step):
        r = top + int(round((geometry.ymax - yv) * px_per_m))
        cv2.line(out, (left - 5, r), (left, r), (60, 60, 60), 1)
        label = f"{yv:g}"
        _text(out, label, (left - 8 - 8 * len(label), r + 4), 0.38)
    _text(out, "y (m)", (4, top - 6), 0.4)
    _legend(out, left + mw + 14, top, legend, marks)
    return out


def _legend(out: np.ndarray, x: int, y: int, legend: dict[str, Any], marks: Marks) -> None:
    kind = legend.get("kind")
    if kind == "ramp":
        lut = np.array(legend["colours"], np.uint8)
        ramp = cv2.resize(lut[::-1][:, None, :], (24, 180), interpolation=cv2.INTER_LINEAR)
        out[y:y + 180, x:x + 24] = ramp
        cv2.rectangle(out, (x, y), (x + 24, y + 180), (60, 60, 60), 1)
        lo, hi = float(legend["lo"]), float(legend["hi"])
        _text(out, f"{hi:.3g}", (x + 30, y + 8))
        _text(out, f"{lo:.3g}", (x + 30, y + 180))
        _text(out, str(legend.get("unit", ""))[:22], (x, y + 200))
        for value, label in legend.get("marks", []):
            if hi > lo and lo <= value <= hi:
                r = y + int(round((hi - value) / (hi - lo) * 180))
                cv2.line(out, (x - 4, r), (x + 28, r), (0, 0, 0), 2)
                _text(out, f"{label} {value:.3g}", (x + 30, r + 4))
        y += 216
    elif kind == "classes":
        for (r, g, b, a), label in legend["entries"]:  # the swatch as the map shows it: over white
            out[y:y + 14, x:x + 14] = _hatch(14, 14) * (1 - a / 255) + np.array([r, g, b]) * (a / 255)
            cv2.rectangle(out, (x, y), (x + 14, y + 14), (90, 90, 90), 1)
            _text(out, label, (x + 20, y + 12))
            y += 22
    entries: list[tuple[str, Sequence[int], str]] = [] if kind == "classes" else [("hatch", (0, 0, 0), "unseen")]
    if marks.rover is not None:
        entries.append(("box", ROVER, "rover, arrow: forward"))
    if marks.path is not None:
        entries.append(("line", PATH, "A* path"))
    if marks.waypoints is not None:
        entries.append(("dot", WAYPOINT, "waypoints"))
    if marks.track is not None:
        entries.append(("line", TRACK, "driven track"))
    if marks.goal is not None:
        entries.append(("cross", GOAL, "goal"))
    y += 8
    for shape, colour, label in entries:
        c = tuple(int(v) for v in colour)
        if shape == "hatch":
            out[y:y + 14, x:x + 14] = _hatch(14, 14)
            cv2.rectangle(out, (x, y), (x + 14, y + 14), (90, 90, 90), 1)
        elif shape == "box":
            cv2.rectangle(out, (x, y + 2), (x + 14, y + 12), c, -1)
        elif shape == "line":
            cv2.line(out, (x, y + 7), (x + 14, y + 7), c, 3)
        elif shape == "dot":
            cv2.circle(out, (x + 7, y + 7), 5, c, -1, cv2.LINE_AA)
        else:
            cv2.line(out, (x + 2, y + 2), (x + 12, y + 12), c, 2)
            cv2.line(out, (x + 2, y + 12), (x + 12, y + 2), c, 2)
        _text(out, label, (x + 20, y + 12))
        y += 22
