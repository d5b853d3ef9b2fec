"""Map layers as PNG images for the web console, rendered from the GeoTIFFs on request.

The page draws each layer as one image placed by its grid bounds. A layer is rendered once per
version of its file (path, size, modification time) and kept in a small LRU cache, so every
open page and every redraw after the first costs a dictionary lookup. Undefined cells are
transparent, never black, so the layers below (and the metric grid) show through.
"""

from __future__ import annotations

import threading
from collections import Counter, OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from prox_workflows.grid import GridGeometry, read_geotiff
from prox_workflows.steps.colormaps import colorize

MAX_SIDE = 2048  # larger layers are reduced: a browser draws 2048 px as fast as it needs to

HAZARD_RGBA = {0: (60, 170, 80, 60), 255: (220, 40, 40, 230)}  # safe (light) / hazardous; undefined: clear


@dataclass(frozen=True)
class LayerImage:
    """One rendered layer: the PNG and where it lies on the map."""

    png: bytes
    bounds: tuple[float, float, float, float]  # xmin, ymin, xmax, ymax in metres
    version: str
    legend: dict[str, Any]  # what the colours mean, drawn by the page beside the map


def version_of(path: Path) -> str:
    """Changes whenever the product is rewritten (atomic rename gives a new mtime and inode)."""
    st = path.stat()
    return f"{st.st_mtime_ns:x}-{st.st_size:x}-{st.st_ino:x}"


def _hillshade(dem: np.ndarray, cell: float) -> np.ndarray:
    """Shaded relief, light from the north-west at 45 degrees (the cartographers' convention).

    The surface normal dotted with the light, in float32 without trigonometry per cell: the
    arctan/cos form costs a second on a 2000 x 2000 layer, this a tenth of it."""
    z = np.where(np.isfinite(dem), dem, np.nanmean(dem) if np.isfinite(dem).any() else 0.0).astype(np.float32)
    gx = np.zeros_like(z)
    gy = np.zeros_like(z)
    gx[:, 1:-1] = (z[:, 2:] - z[:, :-2]) / (2 * cell)  # east
    gy[1:-1, :] = (z[:-2, :] - z[2:, :]) / (2 * cell)  # north: row 0 is the northern edge
    alt, az = np.radians(45.0), np.radians(315.0)  # azimuth clockwise from north
    lx, ly, lz = np.cos(alt) * np.sin(az), np.cos(alt) * np.cos(az), np.sin(alt)
    shade = (lz - gx * lx - gy * ly) / np.sqrt(1.0 + gx * gx + gy * gy)
    return np.clip(shade, 0.0, 1.0)


def _range(values: np.ndarray) -> tuple[float | None, float | None]:
    """1st..99th percentile from at most ~250,000 cells: the colour range of a map view does not
    need every cell, and a full percentile is a third of a big layer's render."""
    sample = values[:: max(1, values.shape[0] // 500), :: max(1, values.shape[1] // 500)]
    finite = sample[np.isfinite(sample)]
    if finite.size == 0:
        return None, None
    lo, hi = np.percentile(finite, [1, 99])
    return float(lo), float(hi)


def _reduce(values: np.ndarray) -> np.ndarray:
    h, w = values.shape[:2]
    step = max(1, int(np.ceil(max(h, w) / MAX_SIDE)))
    return values[::step, ::step] if step > 1 else values


def _css(rgb: Any) -> str:
    return "#{:02x}{:02x}{:02x}".format(*(int(c) for c in rgb[:3]))


def _ramp(colormap: int, lo: float, hi: float, unit: str) -> dict[str, Any]:
    ramp = cv2.applyColorMap(np.linspace(0, 255, 6).astype(np.uint8).reshape(6, 1), colormap).reshape(6, 3)
    return {"kind": "ramp", "colours": [_css(c[::-1]) for c in ramp], "lo": lo, "hi": hi, "unit": unit}


UNITS = {"dem": "m", "slope": "deg", "step": "m", "roughness": "m", "variance": "m²", "count": "points"}


def render_layer(name: str, values: np.ndarray, geometry: GridGeometry) -> tuple[np.ndarray, dict[str, Any]]:
    """RGBA uint8 of one layer and its legend, by what the layer means (its name is its kind)."""
    values = _reduce(values)
    if values.ndim == 3:  # an RGB ortho image
        rgb = values[..., :3].astype(np.uint8)
        alpha = np.where(rgb.any(axis=2), 255, 0).astype(np.uint8)
        return np.dstack([rgb, alpha]), {"kind": "image"}
    defined = np.isfinite(values) if values.dtype.kind == "f" else np.ones(values.shape, bool)
    rgba = np.zeros(values.shape + (4,), np.uint8)
    if name == "hazard":
        for value, colour in HAZARD_RGBA.items():
            rgba[values == value] = colour
        return rgba, {"kind": "classes", "entries": [[_css(HAZARD_RGBA[0]), "safe"],
                                                      [_css(HAZARD_RGBA[255]), "hazardous"],
                                                      ["transparent", "undefined"]]}
    if name == "ortho":
        grey = np.nan_to_num(values.astype(np.float32))
        if values.dtype != np.uint8:
            hi = float(np.nanpercentile(grey[defined], 99.5)) if defined.any() else 1.0
            grey = np.clip(grey / max(hi, 1e-9) * 255.0, 0, 255)
        rgba[..., :3] = grey[..., None].astype(np.uint8)
        rgba[..., 3] = np.where(defined & (grey > 0), 255, 0)
        return rgba, {"kind": "image"}
    if name == "traversability":  # green good, red bad
        t = np.clip(np.nan_to_num(values.astype(np.float32)), 0.0, 1.0)
        rgba[..., 0] = (255 * np.clip(2.0 * (1.0 - t), 0, 1)).astype(np.uint8)
        rgba[..., 1] = (200 * np.clip(2.0 * t, 0, 1)).astype(np.uint8)
        rgba[..., 2] = 40
        rgba[..., 3] = np.where(defined, 200, 0)
        return rgba, {"kind": "ramp", "colours": ["#ff0028", "#ffc828", "#00c828"], "lo": 0.0, "hi": 1.0,
                      "unit": "score (0 blocked, 1 good)"}
    if name == "dem":
        cell = geometry.cell * (geometry.width / values.shape[1])
        colour, lo, hi = colorize(values, *_range(values), colormap=cv2.COLORMAP_TURBO)
        shade = _hillshade(values, cell)
        rgba[..., :3] = (colour.astype(np.float32) * (0.35 + 0.65 * shade[..., None])).astype(np.uint8)
        rgba[..., 3] = np.where(defined, 255, 0)
        return rgba, _ramp(cv2.COLORMAP_TURBO, lo, hi, "m (height, hill-shaded)")
    values = values.astype(np.float32)
    colour, lo, hi = colorize(values, *_range(values), colormap=cv2.COLORMAP_VIRIDIS)
    rgba[..., :3] = colour
    rgba[..., 3] = np.where(defined, 230, 0)
    return rgba, _ramp(cv2.COLORMAP_VIRIDIS, lo, hi, UNITS.get(name, ""))


def encode_png(rgba: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError("PNG encoding failed")
    return buf.tobytes()


class LayerCache:
    """Rendered layers by (file, version); thread-safe (renders run in the executor)."""

    def __init__(self, size: int = 24) -> None:
        self.size = size
        self._items: OrderedDict[tuple[str, str], LayerImage] = OrderedDict()
        self._lock = threading.Lock()
        self._inflight: dict[tuple[str, str], threading.Lock] = {}
        self.renders: Counter[str] = Counter()  # renders by layer name (the cache's misses)

    def get(self, name: str, path: Path) -> LayerImage:
        version = version_of(path)
        key = (str(path), version)
        with self._lock:
            hit = self._items.get(key)
            if hit is not None:
                self._items.move_to_end(key)
                return hit
            rendering = self._inflight.setdefault(key, threading.Lock())
        with rendering:  # a second request for a layer being rendered waits for that render
            with self._lock:
                hit = self._items.get(key)
            if hit is not None:
                return hit
            values, geometry = read_geotiff(path)
            rgba, legend = render_layer(name, values, geometry)
            image = LayerImage(encode_png(rgba), geometry.bounds, version, legend)
            with self._lock:
                self.renders[name] += 1
                self._items[key] = image
                self._inflight.pop(key, None)
                while len(self._items) > self.size:
                    self._items.popitem(last=False)
        return image
