"""Dem2Hazard and the planner on real Mars ground: the HiRISE DTM crop (120 x 70 cells of 1.01 m,
DTEEC_010228_1490_016320_1490_A01; slopes median 21 deg, p90 41 deg, max 63 deg).

Why: the hazard map's slope has only been checked on the simulator's terrain, by the code that
computes it. Here an independent computation judges it on ground nobody on the project made: a
least-squares plane fitted to every window by numpy.linalg.lstsq on an explicit design matrix
(Dem2Hazard uses ten windowed sums and a closed-form solve), and Horn's method (Sobel-weighted
differences, what GDAL's gdaldem slope computes) over the same 3 x 3 window. Then the planner
must find its way across the crop through the hazards Dem2Hazard marks.

The shared data lives outside the repository (../shared/realdata, see its README); a clone alone
(CI) skips these tests and says why.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from prox_workflows.algorithms.dem2hazard import dem2hazard
from prox_workflows.algorithms.planner import NavMaps, PlannerParams, plan_path
from prox_workflows.grid import GridGeometry

REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"
DTM = REALDATA / "dem" / "mars_dtm.npy"
CELL = 1.01

needs_dtm = pytest.mark.skipif(not DTM.is_file(), reason=f"shared real data absent: {DTM} "
                               "(the repository's ../shared/realdata; CI clones the repository alone)")

# thresholds at the scale of a 1 m orbital map (the rover's own, 0.15 m steps over 0.3 m, would
# make steep Mars ground one hazard): 3 m window, 30 deg, a 2 m step, 0.5 m roughness
ORBITAL = {"window": 3 * CELL, "slope_max": 30.0, "step_max": 2.0, "roughness_max": 0.5}


def lstsq_slopes(z: np.ndarray, cell: float, n: int) -> np.ndarray:
    """Slope (deg) of the least-squares plane over every full n x n window, by lstsq on the
    design matrix [x y 1]: (H - n + 1) x (W - n + 1), the window centres away from the border."""
    r = n // 2
    windows = np.lib.stride_tricks.sliding_window_view(z, (n, n)).reshape(-1, n * n)
    dy, dx = np.mgrid[-r:r + 1, -r:r + 1]
    design = np.stack([dx.ravel() * cell, -dy.ravel() * cell, np.ones(n * n)], axis=1)
    coef, *_ = np.linalg.lstsq(design, windows.T, rcond=None)
    return np.degrees(np.arctan(np.hypot(coef[0], coef[1]))).reshape(z.shape[0] - 2 * r, z.shape[1] - 2 * r)


@pytest.fixture(scope="module")
def mars() -> tuple[np.ndarray, dict[str, np.ndarray]]:
    z = np.load(DTM).astype(np.float64)
    return z, dem2hazard(z, CELL, ORBITAL)


@needs_dtm
@pytest.mark.parametrize("cells", [3, 5])
def test_slope_agrees_with_an_independent_least_squares_plane_within_1_degree(cells: int) -> None:
    z = np.load(DTM).astype(np.float64)
    out = dem2hazard(z, CELL, {**ORBITAL, "window": cells * CELL})
    r = cells // 2
    ours = out["slope"][r:-r, r:-r].astype(np.float64)
    ref = lstsq_slopes(z, CELL, cells)
    assert np.isfinite(ours).all()
    assert np.max(np.abs(ours - ref)) < 1.0
    assert np.max(np.abs(ours - ref)) < 1e-3  # the same plane, computed another way: float noise only
    assert 15.0 < float(np.median(ours)) < 30.0  # the README's ground: median slope 21 deg


@needs_dtm
def test_slope_agrees_with_horns_method_over_the_same_window(mars) -> None:
    """Horn weighs the centre row and column twice (Sobel), the plane fit weighs all nine cells
    alike, so on rough real ground they differ cell by cell; on nine cells in ten by under 1 deg."""
    z, out = mars
    gx = ndimage.sobel(z, axis=1) / (8 * CELL)
    gy = ndimage.sobel(z, axis=0) / (8 * CELL)
    horn = np.degrees(np.arctan(np.hypot(gx, gy)))[1:-1, 1:-1]
    diff = np.abs(out["slope"][1:-1, 1:-1] - horn)
    assert float(np.median(diff)) < 0.5
    assert float(np.percentile(diff, 90)) < 1.0


@needs_dtm
def test_hazard_marks_the_slopes_beyond_the_limit(mars) -> None:
    z, out = mars
    ref = lstsq_slopes(z, CELL, 3)
    hazard = out["hazard"][1:-1, 1:-1]
    assert np.all(hazard[ref > ORBITAL["slope_max"] + 1.0] == 255)
    safe = hazard == 0
    assert safe.mean() > 0.3 and (hazard == 255).mean() > 0.1  # real ground: both, plenty of each
    assert np.all(ref[safe] <= ORBITAL["slope_max"] + 1.0)


@needs_dtm
def test_the_planner_crosses_the_crop_around_its_hazards(mars) -> None:
    z, out = mars
    g = GridGeometry(CELL, 0.0, z.shape[0] * CELL, z.shape[1], z.shape[0])
    maps = NavMaps(out["hazard"], out["slope"], g)
    xs, ys = g.centers()
    # the largest region of safe ground (a cell clear of hazards all round), and in it the cells
    # nearest the crop's south and north ends: a path the length of the crop, if the planner finds it
    labels, _ = ndimage.label(ndimage.binary_erosion(out["hazard"] == 0, iterations=1), np.ones((3, 3)))
    largest = np.argmax(np.bincount(labels.ravel())[1:]) + 1
    rows, cols = np.nonzero(labels == largest)
    s, e = int(np.argmax(rows)), int(np.argmin(rows))
    start, goal = (xs[cols[s]], ys[rows[s]]), (xs[cols[e]], ys[rows[e]])
    assert goal[1] - start[1] > 80.0
    res = plan_path(maps, None, start, goal, PlannerParams(rover_radius=0.5, margin=0.0, border=0.0,
                                                            critical_slope=30.0))
    assert res.reaches_goal
    r, c = g.cell_of(res.path[:, 0], res.path[:, 1])
    assert np.all(out["hazard"][r, c] != 255)  # every cell the path crosses is safe
    length = float(np.hypot(*np.diff(res.path, axis=0).T).sum())
    assert length >= np.hypot(goal[0] - start[0], goal[1] - start[1])
