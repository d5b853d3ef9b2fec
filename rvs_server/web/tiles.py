"""Map layers as PNG images for the web console, rendered from the GeoTIFFs on request, and the
values under the operator's cursor.

The page draws each layer as one image placed by its grid bounds. A layer is rendered once per
version of its file (path, size, modification time) and kept in a small LRU cache, so every
open page and every redraw after the first costs a dictionary lookup. Undefined cells are
transparent, never black, so the layers below (and the page's "unseen" hatch) show through; so
is the 0 of a 0/1 mask and of a point count (nothing there: a mask is drawn as a mask, and a
count does not colour unseen ground).
"""

from __future__ import annotations

import math
import threading
from collections import Counter, OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from prox_workflows.grid import GridGeometry, read_geotiff
from prox_workflows.layers import LAYERS, LayerSpec, style_of
from prox_workflows.mapview import Style, layer_rgba
from rvs_params.hazard import HAZARDOUS, SAFE, UNDEFINED

MAX_SIDE = 2048  # larger layers are reduced: a browser draws 2048 px as fast as it needs to
MASK_RGBA = (170, 60, 200, 200)  # a 0/1 mask's 1: a colour no ramp or class of the console uses
ZERO_IS_NOTHING = ("0/1", "points")  # units whose 0 means "nothing here" (masks, point counts)
HAZARD_CLASSES = {SAFE: "safe", HAZARDOUS: "hazardous", UNDEFINED: "undefined"}


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


def spec_for(name: str) -> LayerSpec | None:
    """The registry's entry of a console layer (the global hazard map is a hazard map)."""
    return LAYERS.get("hazard" if name == "global_hazard" else name)


def unit_of(name: str) -> str:
    spec = spec_for(name)
    return spec.unit if spec is not None else ""


def dem_meta(dem: Path | None) -> dict[str, Any]:
    """The meta a DEM's sidecar recorded (the Dem2Hazard thresholds its layers were made with):
    the thresholds marked on slope, step and roughness are the ones that made the hazard map."""
    if dem is None:
        return {}
    try:
        info = yaml.safe_load(dem.with_suffix(".yaml").read_text()) or {}
    except (OSError, yaml.YAMLError):
        return {}
    meta = info.get("meta") if isinstance(info, dict) else None
    return meta if isinstance(meta, dict) else {}


def _reduce(values: np.ndarray) -> np.ndarray:
    h, w = values.shape[:2]
    step = max(1, int(np.ceil(max(h, w) / MAX_SIDE)))
    return values[::step, ::step] if step > 1 else values


def render_layer(name: str, values: np.ndarray, geometry: GridGeometry,
                 meta: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """RGBA uint8 of one layer and its legend, styled by the layer registry (as the previews),
    with the registry's meaning in the legend (which end of a score is good)."""
    reduced = _reduce(values)
    cell = geometry.cell * geometry.width / reduced.shape[1]
    spec = spec_for(name)
    if spec is not None and spec.unit == "0/1":
        return _mask_rgba(reduced, spec)
    try:
        style = style_of("hazard" if name == "global_hazard" else name, meta)
    except KeyError:  # a layer the registry does not know: a plain colour ramp
        style = Style()
    rgba, legend = layer_rgba(reduced, style, cell)
    if spec is not None:
        if spec.unit in ZERO_IS_NOTHING:
            rgba[reduced == 0] = 0
        if spec.preview != "classes":  # the classes name themselves
            legend["meaning"] = spec.meaning
    return rgba, legend


def _mask_rgba(values: np.ndarray, spec: LayerSpec) -> tuple[np.ndarray, dict[str, Any]]:
    rgba = np.zeros(values.shape + (4,), np.uint8)
    rgba[values == 1] = MASK_RGBA
    return rgba, {"kind": "classes", "entries": [[list(MASK_RGBA), "1"], [[0, 0, 0, 0], "0"]],
                  "meaning": spec.meaning}


def encode_png(rgba: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise ValueError("PNG encoding failed")
    return buf.tobytes()


class _Versioned:
    """An LRU of things made from one version of a file, each made once even when asked for by
    several threads at a time (renders and reads run in the executor)."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._items: OrderedDict[tuple[str, str], Any] = OrderedDict()
        self._lock = threading.Lock()
        self._inflight: dict[tuple[str, str], threading.Lock] = {}

    def get(self, path: Path, make: Any) -> tuple[Any, bool]:
        """(the item, whether this call made it)."""
        key = (str(path), version_of(path))
        with self._lock:
            hit = self._items.get(key)
            if hit is not None:
                self._items.move_to_end(key)
                return hit, False
            making = self._inflight.setdefault(key, threading.Lock())
        with making:  # a second request for an item being made waits for it
            with self._lock:
                hit = self._items.get(key)
            if hit is not None:
                return hit, False
            item = make(key[1])
            with self._lock:
                self._items[key] = item
                self._inflight.pop(key, None)
                while len(self._items) > self.size:
                    self._items.popitem(last=False)
        return item, True


class LayerCache:
    """Rendered layers by (file, version); thread-safe."""

    def __init__(self, size: int = 24) -> None:
        self._cache = _Versioned(size)
        self.renders: Counter[str] = Counter()  # renders by layer name (the cache's misses)

    def get(self, name: str, path: Path, dem: Path | None = None) -> LayerImage:
        """``dem``: the DEM whose sidecar holds the thresholds the layer is marked with."""

        def make(version: str) -> LayerImage:
            values, geometry = read_geotiff(path)
            rgba, legend = render_layer(name, values, geometry, dem_meta(dem))
            return LayerImage(encode_png(rgba), geometry.bounds, version, legend)

        image, made = self._cache.get(path, make)
        if made:
            self.renders[name] += 1
        return image


class ValueCache:
    """Layer values by (file, version), for the hover readout: a few layers of the current map,
    read once, then a cell lookup per question (thread-safe)."""

    def __init__(self, size: int = 12) -> None:
        self._cache = _Versioned(size)

    def at(self, name: str, path: Path, x: float, y: float) -> dict[str, Any]:
        """The cell's value with the layer's unit; ``value`` None off the grid or where the
        layer has nothing (NaN, the hazard map's undefined, a count's 0 stays 0)."""
        values, geometry = self._cache.get(path, lambda _v: read_geotiff(path))[0]
        row, col = geometry.cell_of(np.array([x]), np.array([y]))
        r, c = int(row[0]), int(col[0])
        out: dict[str, Any] = {"value": None, "unit": unit_of(name)}
        if not (0 <= r < geometry.height and 0 <= c < geometry.width):
            return out
        v = values[r, c]
        if np.ndim(v):  # an RGB image: its grey level
            v = float(np.mean(v))
        v = float(v)
        if not math.isfinite(v):
            return out
        if name in ("hazard", "global_hazard"):
            out["class"] = HAZARD_CLASSES.get(int(v), str(int(v)))
            if int(v) == UNDEFINED:
                return out
        out["value"] = v
        return out
