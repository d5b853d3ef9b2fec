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
from prox_workflows.layers import style_of
from prox_workflows.mapview import Style, layer_rgba

MAX_SIDE = 2048  # larger layers are reduced: a browser draws 2048 px as fast as it needs to


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


def _reduce(values: np.ndarray) -> np.ndarray:
    h, w = values.shape[:2]
    step = max(1, int(np.ceil(max(h, w) / MAX_SIDE)))
    return values[::step, ::step] if step > 1 else values


def render_layer(name: str, values: np.ndarray, geometry: GridGeometry,
                 meta: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """RGBA uint8 of one layer and its legend, styled by the layer registry (as the previews)."""
    reduced = _reduce(values)
    cell = geometry.cell * geometry.width / reduced.shape[1]
    try:
        style = style_of("hazard" if name == "global_hazard" else name, meta)
    except KeyError:  # a layer the registry does not know: a plain colour ramp
        style = Style()
    return layer_rgba(reduced, style, cell)


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
