"""Hole filling: exact on planes, float32 precision kept, big gaps and the outside left alone."""

from __future__ import annotations

import numpy as np
import pytest

from prox_workflows.algorithms.holes import fill_holes, fill_layers, fillable
from prox_workflows.grid import GridGeometry, Layers

CELL = 0.02


def grid(h: int = 120, w: int = 150) -> tuple[np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[0:h, 0:w]
    return xx * CELL, yy * CELL


def test_plane_with_scattered_holes_is_filled_exactly() -> None:
    x, y = grid()
    plane = (1.234 + 0.31 * x - 0.17 * y).astype(np.float32)
    rng = np.random.default_rng(0)
    holes = rng.random(plane.shape) < 0.35
    dem = np.where(holes, np.nan, plane).astype(np.float32)
    out, filled = fill_holes(dem, CELL, 0.06)
    assert out.dtype == np.float32
    assert np.array_equal(filled, holes)  # every scattered hole is small
    assert np.max(np.abs(out[holes] - plane[holes])) < 2e-6
    assert np.array_equal(out[~holes], dem[~holes])  # measured cells untouched


def test_big_gaps_and_the_outside_stay_undefined() -> None:
    x, y = grid()
    dem = (0.5 + 0.1 * x).astype(np.float32)
    dem[40:80, 50:90] = np.nan  # a 0.8 m gap: occlusion shadow
    dem[10:12, 10:13] = np.nan  # a 2 x 3 cell hole
    dem[:, 130:] = np.nan  # unseen beyond the scan
    out, filled = fill_holes(dem, CELL, 0.06)
    assert filled[10:12, 10:13].all()
    assert not filled[43:77, 53:87].any()  # the gap's interior
    assert not filled[:, 133:].any()  # no extrapolation beyond the data
    assert np.isnan(out[60, 70]) and np.isnan(out[60, 140])
    # exactly the cells of the closing: a 3-cell disk fits in neither small hole's place
    assert np.array_equal(filled, fillable(np.isfinite(dem), 3.0))


def test_radius_decides_which_gaps_are_small() -> None:
    x, _ = grid(60, 60)
    dem = (0.2 * x).astype(np.float32)
    dem[20:40, 28:33] = np.nan  # a slot 5 cells (0.1 m) wide
    narrow = fill_holes(dem, CELL, 0.04)[1]  # a 2-cell disk fits: a real gap ...
    assert not narrow[23:37].any() and narrow.sum() <= 12  # ... but for its corners
    out, filled = fill_holes(dem, CELL, 0.06)  # a 3-cell disk does not: a hole
    assert filled[20:40, 28:33].all()
    assert np.allclose(out[20:40, 28:33], (0.2 * x)[20:40, 28:33], atol=1e-6)
    assert not fill_holes(dem, CELL, 0.0)[1].any()


def test_sub_millimetre_relief_survives() -> None:
    x, y = grid()
    surface = (250.0 + 0.0004 * np.sin(6 * x) * np.cos(5 * y)).astype(np.float32)  # 0.4 mm ripples at 250 m
    rng = np.random.default_rng(1)
    holes = rng.random(surface.shape) < 0.2
    dem = np.where(holes, np.nan, surface).astype(np.float32)
    out, filled = fill_holes(dem, CELL, 0.04)
    assert filled[holes].all()
    err = np.abs(out[holes].astype(np.float64) - surface[holes])
    assert err.max() < 5e-5  # 8-bit quantisation of a 0.8 mm range would be 3 um steps at best,
    # but of the usual metres of relief, centimetres; here the ripple's shape is kept
    ripple = surface[holes] - 250.0
    assert np.corrcoef(out[holes] - 250.0, ripple)[0, 1] > 0.99


def test_smooth_surface_is_filled_accurately() -> None:
    x, y = grid()
    surface = (0.3 * np.sin(x) + 0.2 * np.cos(1.5 * y)).astype(np.float32)
    rng = np.random.default_rng(2)
    holes = rng.random(surface.shape) < 0.3
    dem = np.where(holes, np.nan, surface).astype(np.float32)
    out, filled = fill_holes(dem, CELL, 0.06)
    assert np.array_equal(filled, holes)
    # first order: exact for the tangent plane, off by the curvature (0.45 / m) over the support
    assert np.max(np.abs(out[filled] - surface[filled])) < 1e-3
    assert np.sqrt(np.mean((out[filled] - surface[filled]) ** 2)) < 2e-4


def test_layers_version_marks_filled_cells() -> None:
    g = GridGeometry(CELL, 0.0, 1.0, 50, 50)
    layers = Layers(g)
    dem = np.ones(g.shape, np.float32)
    dem[10, 10] = np.nan
    layers["dem"] = dem
    layers["count"] = np.ones(g.shape, np.int32)
    out = fill_layers(layers, 0.04)
    assert out["filled"].dtype == np.uint8
    assert out["filled"][10, 10] == 1 and out["filled"].sum() == 1
    assert out["dem"][10, 10] == pytest.approx(1.0)
    assert np.isnan(layers["dem"][10, 10])  # the input is not changed
    assert out["count"] is layers["count"]


def test_nothing_to_fill() -> None:
    dem = np.ones((5, 5), np.float32)
    out, filled = fill_holes(dem, CELL, 0.1)
    assert not filled.any() and np.array_equal(out, dem)
    empty = np.full((5, 5), np.nan, np.float32)
    out, filled = fill_holes(empty, CELL, 0.1)
    assert not filled.any() and np.isnan(out).all()
    with pytest.raises(ValueError):
        fill_holes(dem, 0.0, 0.1)
