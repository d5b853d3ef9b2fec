"""Build a scene's heightfield and albedo from primitives listed in its YAML file.

Each primitive is one dict with a ``type`` and its parameters (metres, degrees), applied in
order to a grid that starts at ``base_height``:

- ``plane``      gx, gy (slopes), x0, y0 (where it is zero), clip: [lo, hi] (optional)
- ``hill``       x, y, amp, sigma (or sx, sy), yaw: a gaussian bump (negative amp: a hollow)
- ``roughness``  amplitude, scales: [m, ...], bounds (optional): fractal relief
- ``rock``       x, y, d (or a, b), h, yaw, shape: ellipsoid | cap, embed, albedo, roughness:
                 a rock resting on the local ground (union with what is there: max);
                 roughness (default 0, random rocks 0.12) makes its surface knobbly
- ``rocks``      n, bounds, d: [min, max], h_ratio: [min, max]: n rocks of uniform size
- ``rock_field`` bounds, k, d_min, d_max, h_ratio, exclude: [[x, y, r], ...]: rocks drawn from
                 the Golombek & Rapp (1997) size-frequency model, cumulative area fraction
                 F(D) = k exp(-q D), q = 1.79 + 0.152 / k
- ``crater``     x, y, r (rim radius), depth, rim (rim height): bowl plus a rim decaying as r^-3
- ``crater_field`` bounds, n, r_min, r_max, power: n craters, radii from a power law
- ``box``        x, y, sx, sy, yaw, h, albedo: a block standing on the ground (vertical sides)
- ``steps``      x, y, yaw, n, rise, run, width, albedo: a staircase rising along +yaw
- ``sandbox``    x, y, sx, sy, yaw, wall_thickness, wall_height, fill, grain, albedo,
                 wall_albedo: a framed box of sand whose grain coarsens across it
- ``sand``       bounds, albedo, ripple_amp, wavelength, direction, roughness: a sand patch

Random placement draws from the scene's seeded generator, so a seed fixes the world.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from drivers.sim.albedo import load_texture, sample_periodic
from drivers.sim.heightfield import Heightfield
from drivers.sim.noise import fractal
from drivers.sim.settings import AlbedoSettings


class _Grid:
    """Mutable build state: node coordinates, heights, albedo, and a shared speckle field."""

    def __init__(self, bounds: list[float], cell: float, base: float, albedo: float, contrast: float,
                 rng: np.random.Generator) -> None:
        xmin, ymin, xmax, ymax = (float(b) for b in bounds)
        self.cell = float(cell)
        self.nx = int(round((xmax - xmin) / self.cell)) + 1
        self.ny = int(round((ymax - ymin) / self.cell)) + 1
        self.x0, self.y0 = xmin, ymin
        self.xs = xmin + np.arange(self.nx) * self.cell
        self.ys = ymin + np.arange(self.ny) * self.cell
        self.z = np.full((self.ny, self.nx), float(base), np.float64)
        self.rng = rng
        # Speckle: cm-to-dm mottling reused by every primitive's albedo, so surfaces carry
        # texture at all scales, not only flat colour.
        self.speckle = fractal((self.ny, self.nx), self.cell, [0.5, 0.15, 0.04, 0.015], rng, falloff=0.8)
        self.albedo = (albedo * (1.0 + contrast * self.speckle)).astype(np.float64)
        self.rocks: list[dict[str, float]] = []  # ground truth for hazard tests: every rock placed
        self.base_dir: Path | None = None  # the scene file's folder: where relative data files are

    def window(self, xmin: float, ymin: float, xmax: float, ymax: float):
        """Index slices and node coordinates of the part of the grid inside a box, or None."""
        j0 = max(int(np.floor((xmin - self.x0) / self.cell)), 0)
        j1 = min(int(np.ceil((xmax - self.x0) / self.cell)) + 1, self.nx)
        i0 = max(int(np.floor((ymin - self.y0) / self.cell)), 0)
        i1 = min(int(np.ceil((ymax - self.y0) / self.cell)) + 1, self.ny)
        if j0 >= j1 or i0 >= i1:
            return None
        sl = (slice(i0, i1), slice(j0, j1))
        X, Y = np.meshgrid(self.xs[j0:j1], self.ys[i0:i1])
        return sl, X, Y

    def ground(self, x: float, y: float) -> float:
        """Bilinear height of the grid built so far (what a new object rests on)."""
        fx = np.clip((x - self.x0) / self.cell, 0, self.nx - 1.000001)
        fy = np.clip((y - self.y0) / self.cell, 0, self.ny - 1.000001)
        j, i = int(fx), int(fy)
        u, v = fx - j, fy - i
        z = self.z
        return float(z[i, j] * (1 - u) * (1 - v) + z[i, j + 1] * u * (1 - v)
                     + z[i + 1, j] * (1 - u) * v + z[i + 1, j + 1] * u * v)


def _local(X: np.ndarray, Y: np.ndarray, x: float, y: float, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
    dx, dy = X - x, Y - y
    return c * dx + s * dy, -s * dx + c * dy


def _bounds_mask(g: _Grid, bounds: list[float] | None) -> tuple[Any, np.ndarray, np.ndarray] | None:
    if bounds is None:
        X, Y = np.meshgrid(g.xs, g.ys)
        return (slice(None), slice(None)), X, Y
    return g.window(*bounds)


def plane(g: _Grid, p: dict) -> None:
    w = _bounds_mask(g, p.get("bounds"))
    if w is None:
        return
    sl, X, Y = w
    dz = p.get("gx", 0.0) * (X - p.get("x0", 0.0)) + p.get("gy", 0.0) * (Y - p.get("y0", 0.0))
    if "clip" in p:
        dz = np.clip(dz, *p["clip"])
    g.z[sl] += dz


def hill(g: _Grid, p: dict) -> None:
    sx = float(p.get("sx", p.get("sigma", 1.0)))
    sy = float(p.get("sy", p.get("sigma", sx)))
    r = 4.0 * max(sx, sy)
    w = g.window(p["x"] - r, p["y"] - r, p["x"] + r, p["y"] + r)
    if w is None:
        return
    sl, X, Y = w
    a, b = _local(X, Y, p["x"], p["y"], p.get("yaw", 0.0))
    g.z[sl] += p["amp"] * np.exp(-0.5 * ((a / sx) ** 2 + (b / sy) ** 2))


def roughness(g: _Grid, p: dict) -> None:
    w = _bounds_mask(g, p.get("bounds"))
    if w is None:
        return
    sl, X, _ = w
    field = fractal(X.shape, g.cell, p.get("scales", [1.0, 0.3, 0.1]), g.rng, p.get("falloff", 0.6))
    g.z[sl] += p["amplitude"] * field


def rock(g: _Grid, p: dict) -> None:
    a = float(p.get("a", p.get("d", 0.2) / 2.0))
    b = float(p.get("b", a))
    h = float(p.get("h", a))
    x, y = float(p["x"]), float(p["y"])
    r = max(a, b)
    w = g.window(x - r, y - r, x + r, y + r)
    if w is None:
        return
    sl, X, Y = w
    u, v = _local(X, Y, x, y, p.get("yaw", 0.0))
    rn2 = (u / a) ** 2 + (v / b) ** 2
    inside = rn2 < 1.0
    if p.get("shape", "ellipsoid") == "cap":
        # Spherical cap of base radius a and height h (h <= a), stretched to b across.
        R = (a * a + h * h) / (2.0 * h)
        prof = np.sqrt(np.maximum(R * R - rn2 * a * a, 0.0)) - (R - h)
    else:
        prof = h * np.sqrt(np.maximum(1.0 - rn2, 0.0))
    rough = float(p.get("roughness", 0.0))
    if rough:
        # Knobbly surface: the shared fractal field, scaled by the rock's own height, so
        # rocks are not perfect domes (and carry relief that stereo and DEMs can see).
        prof = prof * (1.0 + rough * g.speckle[sl])
    base = g.ground(x, y) - float(p.get("embed", 0.0))
    top = np.where(inside, base + prof, -np.inf)
    g.rocks.append({"x": x, "y": y, "a": a, "b": b, "yaw": float(p.get("yaw", 0.0)),
                    "height": float(prof.max(initial=0.0)) - float(p.get("embed", 0.0))})
    zsl = g.z[sl]
    higher = top > zsl
    g.z[sl] = np.where(higher, top, zsl)
    alb = p.get("albedo")
    if alb is None:
        alb = float(np.clip(g.rng.normal(0.35, 0.12), 0.08, 0.8))
    g.albedo[sl] = np.where(higher, alb * (1.0 + 0.35 * g.speckle[sl]), g.albedo[sl])


def _rock_shape(g: _Grid, d: float, h_ratio: list[float]) -> dict:
    rng = g.rng
    # Elongated footprints keep the area of a disc of diameter d (the size-frequency models
    # count rocks by area-equivalent diameter).
    elong = np.sqrt(rng.uniform(0.65, 1.0))
    return {"a": d / 2.0 / elong, "b": d / 2.0 * elong, "h": d * rng.uniform(*h_ratio), "yaw": rng.uniform(0, 180),
            "embed": d * rng.uniform(0.0, 0.1), "roughness": 0.12}


def _place(g: _Grid, bounds: list[float], n: int, exclude: list[list[float]]) -> tuple[np.ndarray, np.ndarray]:
    """n uniform positions in bounds and the mask of those outside every exclusion disc."""
    xmin, ymin, xmax, ymax = bounds
    pts = np.column_stack([g.rng.uniform(xmin, xmax, n), g.rng.uniform(ymin, ymax, n)])
    keep = np.ones(n, bool)
    for ex, ey, er in exclude:
        keep &= np.hypot(pts[:, 0] - ex, pts[:, 1] - ey) > er
    return pts, keep


def rocks(g: _Grid, p: dict) -> None:
    n = int(p["n"])
    d = g.rng.uniform(*p.get("d", [0.1, 0.3]), n)
    pts, keep = _place(g, p["bounds"], n, p.get("exclude", []))
    for (x, y), di in zip(pts[keep], d[keep], strict=True):
        rock(g, {"x": x, "y": y, **_rock_shape(g, float(di), p.get("h_ratio", [0.3, 0.6]))})


def golombek_counts(k: float, d_min: float, d_max: float, area: float, bins: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """Bin edges of rock diameter and expected rock counts per bin for an area (m^2).

    Golombek & Rapp: cumulative fractional area F(D) = k exp(-q D); the number density per
    diameter follows as n(D) = -dF/dD / (pi D^2 / 4) = 4 k q exp(-q D) / (pi D^2).
    """
    q = 1.79 + 0.152 / k
    edges = np.geomspace(d_min, d_max, bins + 1)
    mid = np.sqrt(edges[:-1] * edges[1:])
    dens = 4.0 * k * q * np.exp(-q * mid) / (np.pi * mid**2)
    return edges, dens * np.diff(edges) * area


def rock_field(g: _Grid, p: dict) -> None:
    xmin, ymin, xmax, ymax = p["bounds"]
    edges, lam = golombek_counts(float(p.get("k", 0.05)), float(p.get("d_min", 0.05)),
                                 float(p.get("d_max", 1.0)), (xmax - xmin) * (ymax - ymin))
    counts = g.rng.poisson(lam)
    d = np.concatenate([g.rng.uniform(edges[i], edges[i + 1], c) for i, c in enumerate(counts) if c])
    # Big rocks first so small ones drape over them, not the other way round.
    d = np.sort(d)[::-1]
    pts, keep = _place(g, p["bounds"], len(d), p.get("exclude", []))
    for (x, y), di in zip(pts[keep], d[keep], strict=True):
        rock(g, {"x": x, "y": y, **_rock_shape(g, float(di), p.get("h_ratio", [0.3, 0.6]))})


def crater(g: _Grid, p: dict) -> None:
    x, y, R = float(p["x"]), float(p["y"]), float(p["r"])
    depth = float(p.get("depth", 0.2 * R))
    rim = float(p.get("rim", 0.08 * R))
    reach = 3.0 * R
    w = g.window(x - reach, y - reach, x + reach, y + reach)
    if w is None:
        return
    sl, X, Y = w
    r = np.hypot(X - x, Y - y) / R
    inner = rim - (depth + rim) * (1.0 - r**2)
    # Outside the rim: r^-3 falloff, shifted to reach zero at 3 R so there is no seam.
    outer = rim * (np.maximum(r, 1.0) ** -3 - 1.0 / 27.0) / (1.0 - 1.0 / 27.0)
    dz = np.where(r < 1.0, inner, np.where(r < 3.0, outer, 0.0))
    g.z[sl] += dz
    tint = float(p.get("tint", -0.08))
    g.albedo[sl] *= 1.0 + tint * np.clip(1.0 - r, 0.0, 1.0)


def crater_field(g: _Grid, p: dict) -> None:
    n = int(p["n"])
    r_min, r_max = float(p.get("r_min", 0.3)), float(p.get("r_max", 2.0))
    power = float(p.get("power", -2.0))
    # Inverse-CDF sampling of a power law N(>r) ~ r^power between r_min and r_max.
    u = g.rng.uniform(0, 1, n)
    a, b = r_min**power, r_max**power
    r = (a + u * (b - a)) ** (1.0 / power)
    pts, keep = _place(g, p["bounds"], n, p.get("exclude", []))
    for (x, y), ri in zip(pts[keep], r[keep], strict=True):
        crater(g, {"x": x, "y": y, "r": ri, "depth": ri * g.rng.uniform(0.12, 0.25),
                   "rim": ri * g.rng.uniform(0.03, 0.08)})


def _rect(g: _Grid, p: dict, sx: float, sy: float, cx: float = 0.0):
    x, y = float(p["x"]), float(p["y"])
    r = np.hypot(sx, sy) / 2.0 + abs(cx) + g.cell
    w = g.window(x - r, y - r, x + r, y + r)
    if w is None:
        return None
    sl, X, Y = w
    a, b = _local(X, Y, x, y, p.get("yaw", 0.0))
    return sl, a, b


def box(g: _Grid, p: dict) -> None:
    sx, sy = float(p["sx"]), float(p["sy"])
    w = _rect(g, p, sx, sy)
    if w is None:
        return
    sl, a, b = w
    inside = (np.abs(a) <= sx / 2) & (np.abs(b) <= sy / 2)
    top = p["top"] if "top" in p else g.ground(p["x"], p["y"]) + float(p["h"])
    higher = inside & (top > g.z[sl])
    g.z[sl] = np.where(higher, top, g.z[sl])
    alb = float(p.get("albedo", 0.6))
    g.albedo[sl] = np.where(higher, alb * (1.0 + 0.15 * g.speckle[sl]), g.albedo[sl])


def steps(g: _Grid, p: dict) -> None:
    n, rise, run = int(p.get("n", 3)), float(p.get("rise", 0.05)), float(p.get("run", 0.1))
    width = float(p.get("width", 0.3))
    length = n * run
    # (x, y) is the foot of the first step; the stair rises along +yaw.
    c, s = np.cos(np.radians(p.get("yaw", 0.0))), np.sin(np.radians(p.get("yaw", 0.0)))
    centre = {"x": p["x"] + c * length / 2, "y": p["y"] + s * length / 2, "yaw": p.get("yaw", 0.0)}
    w = _rect(g, centre, length, width)
    if w is None:
        return
    sl, a, b = w
    along = a + length / 2
    inside = (along >= 0) & (along < length) & (np.abs(b) <= width / 2)
    base = g.ground(p["x"], p["y"])
    top = base + rise * (np.floor(np.clip(along, 0, length - 1e-9) / run) + 1)
    higher = inside & (top > g.z[sl])
    g.z[sl] = np.where(higher, top, g.z[sl])
    alb = float(p.get("albedo", 0.55))
    g.albedo[sl] = np.where(higher, alb * (1.0 + 0.15 * g.speckle[sl]), g.albedo[sl])


def sandbox(g: _Grid, p: dict) -> None:
    sx, sy = float(p["sx"]), float(p["sy"])
    t = float(p.get("wall_thickness", 0.02))
    w = _rect(g, p, sx, sy)
    if w is None:
        return
    sl, a, b = w
    base = g.ground(p["x"], p["y"])
    outer = (np.abs(a) <= sx / 2) & (np.abs(b) <= sy / 2)
    inner = (np.abs(a) < sx / 2 - t) & (np.abs(b) < sy / 2 - t)
    frame = outer & ~inner
    # Grain coarsens across the box (seed 000 sect. 4.3.6: "varying grain size").
    fine = fractal(a.shape, g.cell, [0.05, 0.02], g.rng)
    coarse = fractal(a.shape, g.cell, [0.25, 0.1], g.rng)
    ramp = np.clip(a / sx + 0.5, 0.0, 1.0)
    grain = p.get("grain", [0.004, 0.02])
    sand = base + float(p.get("fill", 0.05)) + grain[0] * fine * (1 - ramp) + grain[1] * coarse * ramp
    z = g.z[sl]
    z = np.where(inner, np.maximum(sand, base), z)
    z = np.where(frame, base + float(p.get("wall_height", 0.1)), z)
    g.z[sl] = z
    alb = float(p.get("albedo", 0.6))
    walb = float(p.get("wall_albedo", 0.45))
    g.albedo[sl] = np.where(inner, alb * (1.0 + 0.3 * g.speckle[sl] + 0.15 * fine),
                            np.where(frame, walb * (1.0 + 0.1 * g.speckle[sl]), g.albedo[sl]))


def sand(g: _Grid, p: dict) -> None:
    w = g.window(*p["bounds"])
    if w is None:
        return
    sl, X, Y = w
    xmin, ymin, xmax, ymax = p["bounds"]
    # Soft edges: the patch fades in over `feather` metres.
    f = float(p.get("feather", 0.5))
    edge = np.minimum.reduce([X - xmin, xmax - X, Y - ymin, ymax - Y]) / f
    wgt = np.clip(edge, 0.0, 1.0)
    wgt = wgt * wgt * (3 - 2 * wgt)
    ang = np.radians(p.get("direction", 0.0))
    phase = (np.cos(ang) * X + np.sin(ang) * Y) * 2 * np.pi / float(p.get("wavelength", 0.3))
    wobble = fractal(X.shape, g.cell, [1.0, 0.4], g.rng)
    ripples = float(p.get("ripple_amp", 0.01)) * np.sin(phase + 1.5 * wobble)
    rough = float(p.get("roughness", 0.005)) * fractal(X.shape, g.cell, [0.2, 0.05], g.rng)
    g.z[sl] += wgt * (ripples + rough)
    alb = float(p.get("albedo", 0.4))
    g.albedo[sl] = (1 - wgt) * g.albedo[sl] + wgt * alb * (1.0 + 0.2 * g.speckle[sl])


DATA_DIR = Path(__file__).resolve().parent / "data"


def data_file(name: str, base_dir: Path | None = None) -> Path:
    """A scene's data file: absolute, next to the scene file, or shipped in drivers/sim/data."""
    p = Path(name)
    if p.is_absolute():
        return p
    for root in ([base_dir] if base_dir is not None else []) + [DATA_DIR]:
        if (root / p).is_file():
            return root / p
    raise FileNotFoundError(f"no data file {name!r} next to the scene or in {DATA_DIR}")


def dtm_crop(p: dict, base_dir: Path | None = None) -> tuple[np.ndarray, float, float, float]:
    """The cropped DTM of a ``dtm`` primitive as a north-up grid of node heights (float64, mean
    removed) and the world x, y of its north-west node and its cell: what the orbiter saw, placed
    in the scene's frame. Shared by the terrain builder and the global-map tool so the two agree."""
    z = np.load(data_file(str(p["file"]), base_dir)).astype(np.float64)
    r0, r1, c0, c1 = (int(v) for v in p.get("crop", [0, z.shape[0], 0, z.shape[1]]))
    z = z[r0:r1, c0:c1]
    if z.size == 0 or not np.isfinite(z).all():
        raise ValueError(f"dtm {p['file']}: crop {[r0, r1, c0, c1]} is empty or has undefined heights")
    cell = float(p.get("cell", 1.0))
    cx, cy = (float(v) for v in p.get("center", [0.0, 0.0]))
    rows, cols = z.shape
    x_nw = cx - (cols - 1) / 2.0 * cell
    y_nw = cy + (rows - 1) / 2.0 * cell
    return z - z.mean(), x_nw, y_nw, cell


def dtm(g: _Grid, p: dict) -> None:
    """Heights from a real DTM (a .npy of node heights, row 0 north), bicubically upsampled to
    the grid; ``crop`` [r0, r1, c0, c1] of the file, ``cell`` its spacing, ``center`` where the
    crop's centre lands, ``scale`` a vertical exaggeration (1). Nodes beyond the crop take the
    edge's height. Finer relief (roughness, rocks) comes from the primitives that follow."""
    z, x_nw, y_nw, cell = dtm_crop(p, g.base_dir)
    fx = ((g.xs - x_nw) / cell).astype(np.float32)
    fy = ((y_nw - g.ys) / cell).astype(np.float32)
    mx, my = np.meshgrid(fx, fy)
    up = cv2.remap(z.astype(np.float32), mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    g.z += float(p.get("scale", 1.0)) * up.astype(np.float64)


PRIMITIVES: dict[str, Callable[[_Grid, dict], None]] = {
    "plane": plane, "hill": hill, "roughness": roughness, "rock": rock, "rocks": rocks,
    "rock_field": rock_field, "crater": crater, "crater_field": crater_field, "box": box,
    "steps": steps, "sandbox": sandbox, "sand": sand, "dtm": dtm,
}


def add_rock(hf: Heightfield, x: float, y: float, radius: float, height: float,
             rng: np.random.Generator) -> Heightfield:
    """A copy of ``hf`` with one more rock (a dome of ``radius`` and ``height`` on the ground
    there), built by the same ``rock`` primitive as a scene's, on a small grid around it so a
    large terrain is not rebuilt. Its record joins ``rocks`` (ground truth for hazard checks)."""
    r = float(radius) + 2 * hf.cell
    ny, nx = hf.shape
    j0 = max(int(np.floor((x - r - hf.x0) / hf.cell)), 0)
    j1 = min(int(np.ceil((x + r - hf.x0) / hf.cell)), nx - 1)
    i0 = max(int(np.floor((y - r - hf.y0) / hf.cell)), 0)
    i1 = min(int(np.ceil((y + r - hf.y0) / hf.cell)), ny - 1)
    if j0 >= j1 or i0 >= i1:
        raise ValueError(f"a rock at ({x:.2f}, {y:.2f}) is off the terrain {hf.bounds}")
    bounds = [hf.x0 + j0 * hf.cell, hf.y0 + i0 * hf.cell, hf.x0 + j1 * hf.cell, hf.y0 + i1 * hf.cell]
    g = _Grid(bounds, hf.cell, 0.0, 0.5, 0.25, rng)
    sl = (slice(i0, i0 + g.ny), slice(j0, j0 + g.nx))
    g.z = hf.heights[sl].astype(np.float64)
    g.albedo = hf.albedo[sl].astype(np.float64)
    rock(g, {"x": x, "y": y, "a": radius, "b": radius, "h": height, "roughness": 0.12})
    heights, albedo = hf.heights.copy(), hf.albedo.copy()
    heights[sl] = g.z
    albedo[sl] = np.clip(g.albedo, 0.02, 0.98)
    return Heightfield(hf.x0, hf.y0, hf.cell, heights, albedo, rocks=[*hf.rocks, *g.rocks])


def build_terrain(spec: dict, rng: np.random.Generator, base_dir: str | Path | None = None,
                  albedo: AlbedoSettings | None = None) -> Heightfield:
    """The heightfield a scene's ``terrain`` section describes (``base_dir``: the scene file's
    folder, where its relative data files are looked up first; ``albedo``: the scene's albedo
    block, whose ``mars`` source replaces the ground's procedural speckle by real Mars texture)."""
    g = _Grid(spec["bounds"], spec.get("cell", 0.01), spec.get("base_height", 0.0),
              spec.get("albedo", 0.5), spec.get("albedo_contrast", 0.25), rng)
    g.base_dir = Path(base_dir) if base_dir is not None else None
    if albedo is not None and albedo.source == "mars":
        # The ground (before any primitive paints rocks, sand or steps over it) takes its
        # reflectance from the real frames; the speckle field is still drawn (same random
        # sequence, so the geometry is the same world as the procedural flavour) and still makes
        # rocks knobbly.
        tex = load_texture(data_file(albedo.texture, g.base_dir))
        X, Y = np.meshgrid(g.xs, g.ys)
        rel = sample_periodic(tex, X, Y, albedo.texel_m)
        g.albedo = float(spec.get("albedo", 0.5)) * (1.0 + albedo.contrast * (rel.astype(np.float64) - 1.0))
    for p in spec.get("primitives", []):
        kind = p.get("type")
        if kind not in PRIMITIVES:
            raise ValueError(f"unknown terrain primitive {kind!r}; known: {sorted(PRIMITIVES)}")
        PRIMITIVES[kind](g, p)
    return Heightfield(g.x0, g.y0, g.cell, g.z.astype(np.float32), np.clip(g.albedo, 0.02, 0.98).astype(np.float32),
                       rocks=g.rocks)
