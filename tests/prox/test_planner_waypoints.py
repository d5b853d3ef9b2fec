"""Waypoints: the border cut, the straight-line approximation (seed 000 eq. 12-14) with its
hazard check, the exact segment rasterisation, headings and turns."""

from __future__ import annotations

import numpy as np
import pytest

from prox_workflows.algorithms.waypoints import (
    cut_at_border,
    make_waypoints,
    segment_cells,
    segment_clear,
    simplify,
)
from prox_workflows.grid import GridGeometry


def polyline_distance(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance of each point to a polyline (every point against every leg at once)."""
    if len(line) == 1:
        return np.hypot(*(points - line[0]).T)
    a, ab = line[:-1], np.diff(line, axis=0)  # (M, 2) legs
    rel = points[:, None, :] - a[None]  # (N, M, 2)
    t = np.clip(np.einsum("nmk,mk->nm", rel, ab) / np.maximum(np.einsum("mk,mk->m", ab, ab), 1e-300), 0, 1)
    return np.hypot(*np.moveaxis(rel - t[..., None] * ab[None], -1, 0)).min(axis=1)


def densify(line: np.ndarray, step: float) -> np.ndarray:
    out = [line[:1]]
    for a, b in zip(line[:-1], line[1:], strict=True):
        n = max(2, int(np.ceil(np.hypot(*(b - a)) / step)) + 1)
        out.append(a + np.linspace(0, 1, n)[1:, None] * (b - a))
    return np.concatenate(out)


def test_cut_at_border() -> None:
    assert cut_at_border(np.array([5, 5, 5, 0.1, 5]), 1.0) == 3
    assert cut_at_border(np.array([5, 5, 5]), 1.0) == 3  # never near the border: the whole path
    # the rover stands near the border (or in a blind spot): cut after it has been inside
    assert cut_at_border(np.array([0, 0.5, 2, 2, 0.5, 2]), 1.0) == 4
    assert cut_at_border(np.array([0, 0.5, 0.2]), 1.0) == 1  # never inside: stay
    assert cut_at_border(np.array([1.0, 0.99]), 1.0) == 1


def test_straight_and_l_shaped_paths() -> None:
    line = np.stack([np.arange(20) * 0.1, np.zeros(20)], axis=1)
    assert simplify(line, 0.01).tolist() == [0, 19]
    ell = np.concatenate([line, np.stack([np.full(10, 1.9), np.arange(1, 11) * 0.1], axis=1)])
    assert simplify(ell, 0.01).tolist() == [0, 19, 29]
    assert simplify(line[:2], 0.01).tolist() == [0, 1]
    assert simplify(line[:1], 0.01).tolist() == [0]


def test_eq14_greedy_stretch() -> None:
    # a staircase (the typical octile A* path at a shallow angle) within the deviation is one leg
    stair = np.array([[i * 0.05, (i // 4) * 0.05] for i in range(40)])
    assert simplify(stair, 0.05).tolist() == [0, 39]
    # with a deviation below the step height it needs more legs, each within the deviation
    keep = simplify(stair, 0.01)
    assert len(keep) > 2
    assert polyline_distance(stair, stair[keep]).max() <= 0.01 + 1e-12


def test_simplified_polyline_stays_within_deviation_of_random_walks() -> None:
    rng = np.random.default_rng(1)
    for _ in range(50):
        steps = rng.choice([-1, 0, 1], size=(80, 2), p=[0.2, 0.3, 0.5])
        steps[np.all(steps == 0, axis=1)] = (1, 0)
        path = np.concatenate([[[0, 0]], np.cumsum(steps, axis=0)]) * 0.05
        dev = rng.uniform(0.01, 0.3)
        keep = simplify(path, dev)
        poly = path[keep]
        assert keep[0] == 0 and keep[-1] == len(path) - 1
        assert polyline_distance(path, poly).max() <= dev + 1e-9  # every A* point near a leg
        # the path's legs as they are: densified, they are the same polyline
        assert polyline_distance(densify(poly, 0.005), path).max() <= dev + 0.005


def test_simplification_never_crosses_a_hazard() -> None:
    geom = GridGeometry(0.1, 0.0, 2.0, 20, 20)
    blocked = np.zeros(geom.shape, bool)
    blocked[5:10, 5:10] = True  # a block the path goes around, corner at (0.95, 1.05)
    xs, ys = geom.centers()
    path = np.array([[xs[c], ys[r]] for r, c in
                     [(12, 2), (11, 3), (10, 4), (10, 5), (10, 6), (10, 7), (10, 8), (10, 9), (10, 10),
                      (9, 10), (8, 10), (7, 10), (6, 11), (5, 12), (4, 13)]])
    loose = simplify(path, 1.0)  # no hazard check: one straight leg across the block
    assert len(loose) == 2 and not segment_clear(path[0], path[-1], blocked, geom)
    keep = simplify(path, 1.0, blocked=blocked, geometry=geom)
    for a, b in zip(path[keep][:-1], path[keep][1:], strict=True):
        assert segment_clear(a, b, blocked, geom)
        dense = densify(np.array([a, b]), 0.001)
        r, c = geom.cell_of(dense[:, 0], dense[:, 1])
        assert not blocked[r, c].any()


def test_segment_cells_are_exact() -> None:
    geom = GridGeometry(0.25, -1.0, 1.0, 8, 8)
    rng = np.random.default_rng(3)
    for _ in range(200):
        a, b = rng.uniform(-0.99, 0.99, (2, 2))
        rows, cols = segment_cells(a, b, geom)
        t = np.linspace(0, 1, 100001)
        r, c = geom.cell_of(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]))
        np.testing.assert_array_equal(np.unique(rows * geom.width + cols), np.unique(r * geom.width + c))
    # leaving the grid is not clear
    assert not segment_clear(np.array([0.0, 0.0]), np.array([1.5, 0.0]), np.zeros(geom.shape, bool), geom)


def test_headings_and_turns() -> None:
    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    wp = make_waypoints(square, start_heading=90.0)
    assert wp.heading_deg.tolist() == [0.0, 90.0, 180.0, 180.0]
    assert wp.turn_deg.tolist() == [-90.0, 90.0, 90.0, 0.0]
    assert wp.leg_length.tolist() == [1.0, 1.0, 1.0, 0.0]
    # unknown start heading: the first turn is unknown; turns wrap across +-180
    wp = make_waypoints(np.array([[0, 0], [-1, 0.1763], [-2, 0]]))  # about 170 deg then -170 deg
    assert np.isnan(wp.turn_deg[0])
    assert wp.turn_deg[1] == pytest.approx(20.0, abs=0.01)
    assert wp.rows()[0]["turn_deg"] is None
    # arrival with a goal heading
    wp = make_waypoints(np.array([[0, 0], [0, -2]]), start_heading=0.0, goal_heading=180.0)
    assert wp.heading_deg.tolist() == [-90.0, -90.0] and wp.turn_deg.tolist() == [-90.0, -90.0]
    # no move
    wp = make_waypoints(np.array([[3.0, 4.0]]), start_heading=10.0, goal_heading=-10.0)
    assert len(wp) == 1 and wp.turn_deg[0] == -20.0 and wp.leg_length[0] == 0.0
