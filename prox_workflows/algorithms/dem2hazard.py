"""Dem2Hazard (seed 000 sect. 3.1.6, 4.3.3, 5.3): slope, roughness and step maps of a DEM, each
against its threshold, combined into a hazard map and a continuous traversability layer.

Definitions, for the square window of ``window`` metres (an odd number of cells) around a cell:

- slope: the angle between the z axis and the normal of the *regression plane*
  z = a*x + b*y + c fitted by least squares over the window's defined cells, "a best fit plane
  only taking into account errors in the Z direction" (seed 000, footnote 5);
- roughness: the standard deviation of those cells about that plane, sqrt(RSS / (N - 3)), N - 3
  because the plane took three degrees of freedom, so that on a plane with Gaussian noise it
  estimates the noise's sigma without bias (seed 003 alg. 4 uses an RMS with N - 1);
- step: the greatest height above the local minimum within the window, i.e. max - min over the
  window's defined cells. Seed 000 calls the step map "the deviation from the local minimum";
  seed 003 alg. 1 (ETH's step filter, first pass) computes exactly max - min over a window. Using
  the window's highest cell rather than the centre cell's own height means a cell is judged by
  what a wheel standing on it would meet, so a rock is flagged together with the half-window
  margin around it, which is what a planner needs. ETH's second pass (a step counts only when
  several cells are critical) is left out: the DEM chain fills holes and fuses noise before this.

A cell is undefined (hazard 128, NaN in every float layer) where the DEM is undefined, where
fewer than ``min_fraction`` of the window's cells (and never fewer than 4) are defined, or where the
defined cells are collinear so no plane is determined. Otherwise it is hazardous (255) when any
of slope, roughness or step exceeds its threshold, safe (0) if not.

Traversability follows ETH traversability_estimation: each criterion scores
clip(1 - value / threshold, 0, 1), the scores are combined as a normalised weighted sum, and a
cell past any threshold scores 0; so every hazardous cell has traversability 0.

The plane fit needs only ten windowed sums (1, x, y, z, xx, xy, yy, xz, yz, zz over the defined
cells, in float64), from which slope and the residual variance follow in closed form; the step is
a dilation minus an erosion. The sums, the solve and the slope are one compiled pass per row
(:mod:`._dem2hazard_kernel`, numba): as whole-array box filters and numpy expressions the same
formulas are some sixty passes over grid-sized temporaries, which is what the benchmark's peer
(``tools/bench/dem2hazard.py``) does, and which remains the fallback without numba. Rows are
processed in strips, in parallel threads (the kernel and OpenCV release the GIL); the step's
morphology runs per strip with a halo of half a window, so its temporaries stay small.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from rvs_params import Settings, param
from rvs_params.hazard import (  # the thesis's black / grey / white
    CODES_TEXT,
    HAZARDOUS,
    SAFE,
    UNDEFINED,
)
from rvs_params.jit import HAVE_NUMBA

from ..grid import Layers

CONFIG_PATH = Path(__file__).resolve().parents[2] / "config" / "dem2hazard.yaml"

LAYERS = ("slope", "roughness", "step", "hazard", "traversability")
UNITS = {"slope": "deg", "roughness": "m", "step": "m", "hazard": CODES_TEXT,
         "traversability": "0..1"}

_STRIP_ROWS = 128  # rows per strip (plus halo): a strip's float64 temporaries stay in cache
_WORKERS = min(4, os.cpu_count() or 1)
IMPL = "numba"  # or "numpy": the whole-array filters (what runs when numba is missing)
_kernel_made: list[Callable[..., None]] = []
_kernel_lock = threading.Lock()


@dataclass
class HazardParams(Settings):
    """Thresholds and window of Dem2Hazard: declared once here, with units and ranges; the
    server's ``dem2hazard`` config class derives from this, ``config/dem2hazard.yaml`` sets them."""

    window: float = param(0.3, "side of the square window the plane is fitted over", unit="m", min=0.02, max=5.0)
    step_max: float = param(0.15, "greatest step a wheel may climb", unit="m", min=0.001, max=2.0)
    slope_max: float = param(20.0, "steepest slope the rover may stand on", unit="deg", min=0.1, max=89.0)
    roughness_max: float = param(0.05, "largest spread about the fitted plane", unit="m", min=0.001, max=2.0)
    min_fraction: float = param(0.5, "share of a window's cells that must be defined", min=0.01, max=1.0)
    weight_slope: float = param(1.0, "weight of slope in traversability", min=0.0, max=100.0)
    weight_step: float = param(1.0, "weight of step in traversability", min=0.0, max=100.0)
    weight_roughness: float = param(1.0, "weight of roughness in traversability", min=0.0, max=100.0)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
                raise ValueError(f"dem2hazard: {f.name} must be a finite number, not {value!r}")
            setattr(self, f.name, float(value))
        for name in ("window", "step_max", "slope_max", "roughness_max"):
            if getattr(self, name) <= 0:
                raise ValueError(f"dem2hazard: {name} must be > 0, not {getattr(self, name)}")
        if self.slope_max >= 90:
            raise ValueError(f"dem2hazard: slope_max must be below 90 degrees, not {self.slope_max}")
        if not 0 < self.min_fraction <= 1:
            raise ValueError(f"dem2hazard: min_fraction must be in (0, 1], not {self.min_fraction}")
        weights = (self.weight_slope, self.weight_step, self.weight_roughness)
        if min(weights) < 0 or sum(weights) <= 0:
            raise ValueError(f"dem2hazard: weights must be >= 0 and not all 0, not {weights}")

    def window_cells(self, cell: float) -> int:
        """The window's side in cells: ``window / cell`` rounded, made odd so it has a centre, >= 3."""
        if not cell > 0:
            raise ValueError(f"dem2hazard: cell size must be > 0, not {cell}")
        n = max(3, int(round(self.window / cell)))
        return n if n % 2 else n + 1

    def min_cells(self, cell: float) -> int:
        """Defined cells a window needs: ``min_fraction`` of it, and at least 4 (a plane and a residual)."""
        n = self.window_cells(cell)
        return max(4, math.ceil(self.min_fraction * n * n - 1e-9))

    def as_dict(self) -> dict[str, float]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


def load_params(path: str | Path | None = None, **overrides: Any) -> HazardParams:
    """Parameters from ``config/dem2hazard.yaml`` (or ``path``), then ``overrides``.

    Shared by the server's config and ``rvs-dem2hazard`` so both start from the same defaults;
    unknown keys are errors, not silently ignored.
    """
    data: dict[str, Any] = {}
    source = Path(path) if path is not None else CONFIG_PATH
    if path is not None or source.is_file():
        loaded = yaml.safe_load(source.read_text()) or {}
        if not isinstance(loaded, dict):
            raise ValueError(f"{source}: expected a mapping of key: value")
        data.update(loaded)
    data.update(overrides)
    known = {f.name for f in fields(HazardParams)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(f"dem2hazard: unknown parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    return HazardParams(**data)



def _as_params(params: HazardParams | dict[str, Any] | None) -> HazardParams:
    if params is None:
        return load_params()
    if isinstance(params, HazardParams):
        return params
    if isinstance(params, dict):
        return load_params(**params)
    raise TypeError(f"dem2hazard: params must be HazardParams, a dict or None, not {type(params).__name__}")


# ------------------------------------------------------------------------------ the core


def _box(a: np.ndarray, n: int) -> np.ndarray:
    """Unnormalised n x n window sums; cells beyond the grid count as 0 (i.e. undefined)."""
    return cv2.boxFilter(a, cv2.CV_64F, (n, n), normalize=False, borderType=cv2.BORDER_CONSTANT)


def _strip(zin: np.ndarray, defined: np.ndarray, zref: float, n: int, need: int, cell: float
           ) -> tuple[np.ndarray, ...]:
    """Slope (deg), roughness (m), step (m) and the valid mask for one block of rows, as
    whole-array filters: the implementation without numba, and the kernel's check."""
    z = zin.astype(np.float64) - zref
    h, w = z.shape
    m = defined.astype(np.float64)
    z0 = np.where(defined, z, 0.0)
    # Coordinates in cells, centred on the block so the sums stay small; the fit's covariances
    # do not depend on the origin. y grows northwards (up the raster).
    x = (np.arange(w, dtype=np.float64) - (w - 1) / 2)[None, :]
    y = ((h - 1) / 2 - np.arange(h, dtype=np.float64))[:, None]
    # Window sums over the defined cells, then N^2 times the (co)variances, C_uv = N S_uv - S_u S_v,
    # which the plane and its residual need only as ratios.
    count = _box(m, n)
    valid = defined & (count >= need)
    mx = m * x
    my = np.multiply(m, y, out=m)
    sx, sy, sz = _box(mx, n), _box(my, n), _box(z0, n)

    def cov(u: np.ndarray, v: np.ndarray, su: np.ndarray, sv: np.ndarray) -> np.ndarray:
        out = _box(u * v, n)
        out *= count
        out -= su * sv
        return out

    cxx, cxy, cyy = cov(mx, x, sx, sx), cov(mx, y, sx, sy), cov(my, y, sy, sy)
    del mx, my
    cxz, cyz, czz = cov(z0, x, sx, sz), cov(z0, y, sy, sz), cov(z0, z0, sz, sz)
    del z0, sx, sy, sz
    det = cxx * cyy
    det -= cxy * cxy
    # Collinear cells leave the plane undetermined (det is N^4 times the xy-covariance determinant,
    # in cells^4; a full 3 x 3 window has 1/9).
    valid &= det > 1e-6 * count**4
    det[~valid] = 1.0
    a = cyy * cxz
    a -= cxy * cyz
    a /= det  # dz per cell along x
    b = cxx * cyz
    b -= cxy * cxz
    b /= det  # dz per cell along y
    # Residual sum of squares: N * RSS = Czz - a Cxz - b Cyz.
    rss = czz
    rss -= a * cxz
    rss -= b * cyz
    del cxx, cxy, cyy, cxz, cyz, det
    slope = np.hypot(a, b, out=a)
    slope *= 1.0 / cell
    np.arctan(slope, out=slope)
    np.degrees(slope, out=slope)
    np.maximum(rss, 0.0, out=rss)
    rss /= np.maximum(count * (count - 3.0), 1.0)  # variance about the plane, N - 3 degrees of freedom
    roughness = np.sqrt(rss, out=rss)
    zs = zin if zin.dtype in (np.float32, np.float64) else zin.astype(np.float64)
    return slope, roughness, _step_rows(zs, defined, n), valid


def _plane_kernel() -> Callable[..., None] | None:
    """The compiled plane fit (imported, and compiled or loaded from numba's cache, on first use:
    importing numba costs ~0.3 s), or None without numba or with ``IMPL = "numpy"``."""
    if IMPL != "numba":
        return None
    with _kernel_lock:
        if not _kernel_made:
            if not HAVE_NUMBA:  # pragma: no cover - numba is a core dependency
                return None
            from . import _dem2hazard_kernel as kern

            _kernel_made.append(kern.plane_rows)
    return _kernel_made[0]


def warm_up() -> None:
    """Compile (first run after installing) or load the kernel now, for float32 and float64 DEMs,
    rather than in the first request."""
    for dtype in (np.float32, np.float64):
        dem2hazard(np.zeros((8, 8), dtype), 0.1, load_params(window=0.3))


def _step_rows(z: np.ndarray, defined: np.ndarray, n: int) -> np.ndarray:
    """max - min over each window's defined cells (float64; -inf, NaN where none is defined).

    Dilation minus erosion on the DEM's own values (the selection is exact), undefined cells
    neutral (-inf for max, +inf for min); the morphology border is neutral by default.
    """
    kernel = np.ones((n, n), np.uint8)
    zmax = cv2.dilate(np.where(defined, z, -np.inf), kernel)
    zmin = cv2.erode(np.where(defined, z, np.inf), kernel)
    with np.errstate(over="ignore", invalid="ignore"):  # windows with nothing defined
        return zmax.astype(np.float64) - zmin


def dem2hazard(dem: np.ndarray, cell: float, params: HazardParams | dict[str, Any] | None = None
               ) -> dict[str, np.ndarray]:
    """Slope (deg), roughness (m), step (m) as float32, hazard (uint8 0/128/255) and
    traversability (float32 0..1), each the DEM's shape with NaN (128) where undefined.

    ``dem`` is a float grid in metres, NaN where undefined; ``cell`` its cell size in metres.
    ``params`` defaults to config/dem2hazard.yaml; a dict overrides those defaults.
    """
    p = _as_params(params)
    z = np.asarray(dem)
    if z.ndim != 2:
        raise ValueError(f"dem2hazard: the DEM must be 2-D, not {z.shape}")
    n = p.window_cells(cell)
    need = p.min_cells(cell)
    h, w = z.shape
    if not np.issubdtype(z.dtype, np.floating):
        z = z.astype(np.float64)
    defined_all = np.isfinite(z)
    # Heights relative to one reference: the sums of z and z^2 then keep their precision on
    # DEMs with large absolute heights.
    zref = float(z[defined_all].mean()) if defined_all.any() else 0.0
    halo = n // 2
    kernel = _plane_kernel()
    if kernel is not None:
        # one compiled specialisation per dtype and layout: native float32/float64, C order
        if z.dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
            z = z.astype(np.float64)
        z = np.ascontiguousarray(z)
    out = {name: np.empty((h, w), np.uint8 if name == "hazard" else np.float32) for name in LAYERS}
    slope, roughness, step = out["slope"], out["roughness"], out["step"]
    valid = np.empty((h, w), bool)
    # strips of about 128 K cells: a strip's float64 temporaries stay in the core's L2 cache
    rows = max(32, min(_STRIP_ROWS, (1 << 17) // max(w, 1)))

    def run(r0: int) -> None:
        r1 = min(h, r0 + rows)
        a0, a1 = max(0, r0 - halo), min(h, r1 + halo)
        inner = slice(r0 - a0, r0 - a0 + (r1 - r0))
        v = valid[r0:r1]
        if kernel is not None:
            kernel(z, zref, r0, r1, n, need, 1.0 / cell, slope, roughness, valid)
            t = _step_rows(z[a0:a1], defined_all[a0:a1], n)[inner]
        else:
            s, r, t, vv = _strip(z[a0:a1], defined_all[a0:a1], zref, n, need, cell)
            v[...] = vv[inner]
            t = t[inner]
            for dst, src in ((slope, s), (roughness, r)):
                np.copyto(dst[r0:r1], src[inner], where=v, casting="unsafe")
                dst[r0:r1][~v] = np.nan
        np.copyto(step[r0:r1], t, where=v, casting="unsafe")
        step[r0:r1][~v] = np.nan
        _classify_into(slope[r0:r1], roughness[r0:r1], step[r0:r1], v, p, out["hazard"][r0:r1],
                       out["traversability"][r0:r1])

    starts = range(0, h, rows)
    if len(starts) > 1 and _WORKERS > 1:
        # the kernel, numpy's ufuncs and OpenCV release the GIL: strips run in parallel
        with ThreadPoolExecutor(min(_WORKERS, len(starts))) as pool:
            list(pool.map(run, starts))
    else:
        for r0 in starts:
            run(r0)
    return out


def classify(slope: np.ndarray, roughness: np.ndarray, step: np.ndarray, valid: np.ndarray,
             p: HazardParams) -> dict[str, np.ndarray]:
    """Hazard map and traversability from the three criteria (NaN where undefined); public so
    that criteria computed another way (the benchmark's perfect maps) are judged by the same rule."""
    hazard = np.empty(slope.shape, np.uint8)
    trav = np.empty(slope.shape, np.float32)
    _classify_into(slope, roughness, step, valid, p, hazard, trav)
    return {"slope": slope, "roughness": roughness, "step": step, "hazard": hazard, "traversability": trav}


def _classify_into(slope: np.ndarray, roughness: np.ndarray, step: np.ndarray, valid: np.ndarray,
                   p: HazardParams, hazard: np.ndarray, trav: np.ndarray) -> None:
    """:func:`classify` into given arrays, so that :func:`dem2hazard` classifies each strip while
    it is still in cache."""
    with np.errstate(invalid="ignore"):
        over = (slope > p.slope_max) | (roughness > p.roughness_max) | (step > p.step_max)
    hazard[...] = UNDEFINED
    hazard[valid] = SAFE
    hazard[over & valid] = HAZARDOUS
    total = p.weight_slope + p.weight_step + p.weight_roughness
    trav[...] = 0.0
    for value, crit, weight in ((slope, p.slope_max, p.weight_slope), (step, p.step_max, p.weight_step),
                                (roughness, p.roughness_max, p.weight_roughness)):
        if weight:
            trav += np.float32(weight / total) * np.clip(1.0 - value / np.float32(crit), 0.0, 1.0)
    trav[over] = 0.0
    trav[~valid] = np.nan
    np.clip(trav, 0.0, 1.0, out=trav)  # float rounding of the weighted sum


def hazard_summary(hazard: np.ndarray) -> dict[str, float]:
    """Shares of safe, hazardous and undefined cells (for the CLI's and the server's reports)."""
    total = max(int(hazard.size), 1)
    return {
        "safe": int(np.count_nonzero(hazard == SAFE)) / total,
        "hazardous": int(np.count_nonzero(hazard == HAZARDOUS)) / total,
        "undefined": int(np.count_nonzero(hazard == UNDEFINED)) / total,
    }


def dem2hazard_layers(layers: Layers, params: HazardParams | dict[str, Any] | None = None,
                      layer: str | None = None) -> Layers:
    """The workflow step: the DEM layer (``elevation``, else ``dem``, or ``layer``) in, a new
    :class:`Layers` with the same layers plus slope, roughness, step, hazard, traversability out."""
    p = _as_params(params)
    if layer is None:
        layer = next((name for name in ("elevation", "dem") if name in layers), None)
        if layer is None:
            raise ValueError(f"dem2hazard: no 'elevation' or 'dem' layer (have: {', '.join(layers.layers)})")
    out = Layers(layers.geometry, dict(layers.layers), dict(layers.meta))
    for name, value in dem2hazard(layers[layer], layers.geometry.cell, p).items():
        out[name] = value
    out.meta["dem2hazard"] = {**p.as_dict(), "window_cells": p.window_cells(layers.geometry.cell),
                              "summary": hazard_summary(out["hazard"])}
    return out


# ------------------------------------------------------------------------------ slow reference


def dem2hazard_reference(dem: np.ndarray, cell: float, params: HazardParams | dict[str, Any] | None = None,
                         which: tuple[str, ...] = ("slope", "roughness", "step")) -> dict[str, np.ndarray]:
    """The same slope, roughness and step with ``scipy.ndimage.generic_filter``: one Python call
    and one least-squares solve per cell, the definitions written out plainly.

    The benchmark's peer and the tests' oracle; far too slow for real grids (use crops).
    """
    from scipy import ndimage

    p = _as_params(params)
    z = np.asarray(dem, np.float64)
    n = p.window_cells(cell)
    need = p.min_cells(cell)
    r = n // 2
    dy, dx = np.mgrid[-r:r + 1, -r:r + 1]
    design = np.column_stack([dx.ravel() * cell, -dy.ravel() * cell, np.ones(n * n)])
    centre = (n * n) // 2

    def fit(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        ok = np.isfinite(values)
        if not np.isfinite(values[centre]) or ok.sum() < need:
            return None
        a = design[ok]
        coef, _, rank, _ = np.linalg.lstsq(a, values[ok], rcond=None)
        if rank < 3:
            return None
        return coef, a, values[ok]

    def slope(values: np.ndarray) -> float:
        f = fit(values)
        return np.nan if f is None else math.degrees(math.atan(math.hypot(f[0][0], f[0][1])))

    def rough(values: np.ndarray) -> float:
        f = fit(values)
        if f is None:
            return np.nan
        coef, a, v = f
        res = v - a @ coef
        return math.sqrt(float(res @ res) / max(len(v) - 3, 1))

    def step(values: np.ndarray) -> float:
        ok = np.isfinite(values)
        if not np.isfinite(values[centre]) or ok.sum() < need:
            return np.nan
        return float(values[ok].max() - values[ok].min())

    funcs = {"slope": slope, "roughness": rough, "step": step}
    out = {}
    for name in which:
        out[name] = ndimage.generic_filter(z, funcs[name], size=n, mode="constant", cval=np.nan).astype(np.float32)
    return out
