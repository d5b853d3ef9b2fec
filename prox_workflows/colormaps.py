"""Preview images of map layers, with a colour bar or a legend, for the PNG beside each product.

A GeoTIFF keeps the numbers; the PNG is for a person, so it says what the colours mean: a
continuous layer gets a colour bar with its range, units and marks (a threshold, say) drawn in,
a class layer (the hazard map) gets a legend of swatches. Undefined cells are grey in both, as
in the thesis's hazard maps (seed 000 fig. 33: black safe, white hazardous, grey undefined).

Everything here returns RGB uint8 arrays, ready for :func:`prox_workflows.products.write_png`
(which converts RGB to OpenCV's BGR order itself). Small grids are enlarged (nearest neighbour,
so cells stay square and crisp) and huge ones reduced, so the text stays readable.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from rvs_params.hazard import HAZARDOUS, SAFE
from rvs_params.hazard import UNDEFINED as UNDEFINED_CODE

Colour = tuple[int, int, int]

BLACK: Colour = (0, 0, 0)
WHITE: Colour = (255, 255, 255)
GREY: Colour = (128, 128, 128)
UNDEFINED: Colour = GREY

HAZARD_CLASSES: tuple[tuple[int, Colour, str], ...] = (
    (SAFE, BLACK, "safe"),
    (HAZARDOUS, WHITE, "hazardous"),
    (UNDEFINED_CODE, GREY, "undefined"),
)

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_PANEL_BG: Colour = (255, 255, 255)
_TEXT: Colour = (0, 0, 0)


def _red_yellow_green() -> np.ndarray:
    """A 256-entry LUT (BGR, as cv2.applyColorMap wants): red 0 -> yellow -> green 1."""
    t = np.linspace(0.0, 1.0, 256)
    r = np.where(t < 0.5, 215, 215 - (t - 0.5) * 2 * (215 - 26))
    g = np.where(t < 0.5, 48 + t * 2 * (220 - 48), 220 - (t - 0.5) * 2 * (220 - 150))
    b = np.where(t < 0.5, 39 + t * 2 * (90 - 39), 90 - (t - 0.5) * 2 * (90 - 65))
    return np.stack([b, g, r], axis=1).astype(np.uint8).reshape(256, 1, 3)


RED_YELLOW_GREEN = _red_yellow_green()


def _lut_rgb(colormap: int | np.ndarray) -> np.ndarray:
    """The 256 colours of a colormap, RGB, shape (256, 3)."""
    ramp = np.arange(256, dtype=np.uint8).reshape(256, 1)
    bgr = cv2.applyColorMap(ramp, colormap)
    return bgr.reshape(256, 3)[:, ::-1].copy()


def colorize(values: np.ndarray, lo: float | None = None, hi: float | None = None,
             colormap: int | np.ndarray = cv2.COLORMAP_INFERNO, undefined: Colour = UNDEFINED
             ) -> tuple[np.ndarray, float, float]:
    """(RGB image, lo, hi): values scaled from lo..hi (default: 1st..99th percentile) through an
    OpenCV colormap id or a 256 x 1 x 3 BGR LUT; non-finite cells in the ``undefined`` colour."""
    data = np.asarray(values, dtype=np.float32)
    finite = np.isfinite(data)
    if lo is None or hi is None:
        if finite.any():
            plo, phi = np.percentile(data[finite], [1, 99])
        else:
            plo, phi = 0.0, 1.0
        lo = float(plo) if lo is None else lo
        hi = float(phi) if hi is None else hi
    if not hi > lo:
        hi = lo + 1e-6
    scaled = np.clip((np.where(finite, data, lo) - lo) / (hi - lo), 0.0, 1.0)
    index = np.round(scaled * 255).astype(np.uint8)
    rgb = _lut_rgb(colormap)[index]
    rgb[~finite] = undefined
    return rgb, float(lo), float(hi)


def classes_rgb(labels: np.ndarray, classes: Sequence[tuple[int, Colour, str]] = HAZARD_CLASSES,
                other: Colour = (255, 0, 255)) -> np.ndarray:
    """RGB image of a class map (uint8 labels); labels not listed show in ``other``."""
    lut = np.empty((256, 3), np.uint8)
    lut[:] = other
    for value, colour, _ in classes:
        lut[value] = colour
    return lut[np.asarray(labels, dtype=np.uint8)]


def fit_size(rgb: np.ndarray, min_side: int = 400, max_side: int = 2000) -> np.ndarray:
    """Enlarge small maps by a whole factor (nearest) and shrink huge ones (area average)."""
    h, w = rgb.shape[:2]
    longest = max(h, w)
    if longest < min_side:
        k = int(np.ceil(min_side / longest))
        return np.repeat(np.repeat(rgb, k, axis=0), k, axis=1)
    if longest > max_side:
        s = max_side / longest
        size = (max(1, round(w * s)), max(1, round(h * s)))
        return cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
    return rgb


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float = 0.45,
          colour: Colour = _TEXT) -> None:
    cv2.putText(img, text, org, _FONT, scale, colour, 1, cv2.LINE_AA)


def _fmt(v: float) -> str:
    return f"{v:.3g}"


def _panel(height: int, width: int) -> np.ndarray:
    panel = np.empty((height, width, 3), np.uint8)
    panel[:] = _PANEL_BG
    return panel


def with_colorbar(rgb: np.ndarray, lo: float, hi: float, colormap: int | np.ndarray = cv2.COLORMAP_INFERNO,
                  title: str = "", units: str = "", marks: dict[float, str] | None = None,
                  ticks: int = 5, undefined: Colour | None = UNDEFINED, clipped: bool = True) -> np.ndarray:
    """The image with a panel on its right: title, a vertical colour bar lo (bottom) .. hi (top)
    with tick values and units, optional labelled marks (e.g. a threshold) and an undefined swatch.
    ``clipped`` labels the top "hi+" (values above hi share its colour)."""
    h = max(rgb.shape[0], 260)
    body = rgb
    if rgb.shape[0] < h:
        body = np.vstack([rgb, np.full((h - rgb.shape[0], rgb.shape[1], 3), _PANEL_BG, np.uint8)])
    panel = _panel(h, 150)
    y_top, y_bottom = 44, h - (48 if undefined is not None else 20)
    x0, x1 = 12, 34
    if title:
        _text(panel, title, (8, 18), 0.5)
    if units:
        _text(panel, f"[{units}]", (8, 36), 0.42)
    lut = _lut_rgb(colormap)
    rows = np.linspace(255, 0, y_bottom - y_top).round().astype(int)
    panel[y_top:y_bottom, x0:x1] = lut[rows][:, None, :]
    cv2.rectangle(panel, (x0 - 1, y_top - 1), (x1, y_bottom), _TEXT, 1)

    def y_of(v: float) -> int:
        t = (v - lo) / (hi - lo) if hi > lo else 0.0
        return int(round(y_bottom - 1 - np.clip(t, 0, 1) * (y_bottom - 1 - y_top)))

    mark_rows = [y_of(v) for v in (marks or {})]
    for i in range(ticks):
        v = lo + (hi - lo) * i / max(ticks - 1, 1)
        y = y_of(v)
        cv2.line(panel, (x1, y), (x1 + 4, y), _TEXT, 1)
        if all(abs(y - ym) >= 12 for ym in mark_rows):  # a mark's label takes the place of a tick's
            _text(panel, _fmt(v) + ("+" if clipped and i == ticks - 1 else ""), (x1 + 7, y + 4), 0.4)
    for v, label in (marks or {}).items():
        y = y_of(v)
        cv2.line(panel, (x0 - 4, y), (x1 + 4, y), (220, 0, 0), 2)
        _text(panel, f"{_fmt(v)} {label}", (x1 + 7, y + 4), 0.4, (200, 0, 0))
    if undefined is not None:
        ys = h - 34
        cv2.rectangle(panel, (x0, ys), (x1, ys + 14), undefined, -1)
        cv2.rectangle(panel, (x0, ys), (x1, ys + 14), _TEXT, 1)
        _text(panel, "undefined", (x1 + 7, ys + 12), 0.4)
    return np.hstack([body, panel])


def with_legend(rgb: np.ndarray, entries: Sequence[tuple[Colour, str]], title: str = "") -> np.ndarray:
    """The image with a panel on its right listing colour swatches and their meaning."""
    h = max(rgb.shape[0], 40 + 24 * len(entries))
    body = rgb
    if rgb.shape[0] < h:
        body = np.vstack([rgb, np.full((h - rgb.shape[0], rgb.shape[1], 3), _PANEL_BG, np.uint8)])
    panel = _panel(h, 150)
    if title:
        _text(panel, title, (8, 18), 0.5)
    for i, (colour, label) in enumerate(entries):
        y = 34 + 24 * i
        cv2.rectangle(panel, (10, y), (30, y + 16), colour, -1)
        cv2.rectangle(panel, (10, y), (30, y + 16), _TEXT, 1)
        _text(panel, label, (38, y + 13), 0.45)
    return np.hstack([body, panel])


def layer_preview(values: np.ndarray, lo: float | None = None, hi: float | None = None,
                  colormap: int | np.ndarray = cv2.COLORMAP_INFERNO, title: str = "", units: str = "",
                  marks: dict[float, str] | None = None, clipped: bool = True) -> np.ndarray:
    """A continuous layer as an RGB preview with its colour bar (the usual one-call use)."""
    rgb, lo, hi = colorize(values, lo, hi, colormap)
    return with_colorbar(fit_size(rgb), lo, hi, colormap, title, units, marks, clipped=clipped)


def classes_preview(labels: np.ndarray, classes: Sequence[tuple[int, Colour, str]] = HAZARD_CLASSES,
                    title: str = "hazard", shares: dict[str, float] | None = None) -> np.ndarray:
    """A class map (default: the hazard map) as an RGB preview with its legend; ``shares`` (by
    class name, 0..1) are printed beside the names."""
    entries = []
    for _, colour, name in classes:
        share = (shares or {}).get(name)
        entries.append((colour, name if share is None else f"{name} {100 * share:.1f}%"))
    return with_legend(fit_size(classes_rgb(labels, classes)), entries, title)
