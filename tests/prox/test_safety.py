"""The movement safety gate: unknown ground is never called safe, blocked cells block."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from prox_workflows.algorithms.safety import check_move, sweep_poses
from prox_workflows.grid import GridGeometry

G = GridGeometry(0.05, -5.0, 5.0, 200, 200)


def flat(value: float = 1.0) -> np.ndarray:
    return np.full(G.shape, value, np.float32)


def test_free_ground_is_ok_and_reports_the_worst_cell() -> None:
    t = flat(0.9)
    t[100, 110] = 0.4  # x = 0.525, y = -0.025: under the sweep
    r = check_move(t, G, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0), 0.5, 0.4)
    assert r.verdict == "ok" and r.worst_score == np.float32(0.4)
    assert (r.worst_x, r.worst_y) == pytest.approx((0.525, -0.025))
    assert r.unknown_cells == 0 and r.blocked_cells == 0


def test_blocked_and_unknown() -> None:
    t = flat()
    t[100, 130] = 0.0  # x = 1.525: beyond a 1 m move (front edge at 1.25 + half a cell)
    assert check_move(t, G, (0, 0, 0), (1.0, 0, 0), 0.5, 0.4).verdict == "ok"
    assert check_move(t, G, (0, 0, 0), (1.4, 0, 0), 0.5, 0.4).verdict == "not_traversable"
    t = flat()
    t[100, 120] = np.nan
    r = check_move(t, G, (0, 0, 0), (1.0, 0, 0), 0.5, 0.4)
    assert r.verdict == "unknown" and r.unknown_cells == 1 and abs(r.worst_x - 1.025) < 1e-9
    t[100, 125] = 0.0  # a blocked cell wins over an unknown one
    assert check_move(t, G, (0, 0, 0), (1.5, 0, 0), 0.5, 0.4).verdict == "not_traversable"
    # off the map is unknown
    assert check_move(flat(), G, (4.0, 0, 0), (6.0, 0, 0), 0.5, 0.4).verdict == "unknown"


def test_turning_on_the_spot_sweeps_the_corners() -> None:
    t = flat()
    t[94, 104] = 0.0  # x = 0.225, y = 0.275: beside the rover at 0 deg, inside the disc a turn sweeps
    assert check_move(t, G, (0, 0, 0), (0, 0, 0), 0.6, 0.4).verdict == "ok"
    assert check_move(t, G, (0, 0, 0), (0, 0, 90.0), 0.6, 0.4).verdict == "not_traversable"
    assert len(sweep_poses((0, 0, 0), (0, 0, 90.0), 0.1)) >= 19


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 2**31), st.floats(-2.0, 2.0), st.floats(-2.0, 2.0), st.floats(-180, 180))
def test_never_ok_over_unseen_ground(seed: int, dx: float, dy: float, dyaw: float) -> None:
    rng = np.random.default_rng(seed)
    t = rng.uniform(0.3, 1.0, G.shape).astype(np.float32)
    t[rng.random(G.shape) < 0.002] = np.nan
    r = check_move(t, G, (0.0, 0.0, 0.0), (dx, dy, dyaw), 0.5, 0.4)
    # brute force: every cell whose centre is within the swept rectangles
    xs, ys = G.centers()
    X, Y = np.meshgrid(xs, ys)
    covered = np.zeros(G.shape, bool)
    for x, y, h in sweep_poses((0.0, 0.0, 0.0), (dx, dy, dyaw), 0.1):
        c, s = np.cos(np.radians(h)), np.sin(np.radians(h))
        u, v = (X - x) * c + (Y - y) * s, -(X - x) * s + (Y - y) * c
        covered |= (np.abs(u) <= 0.25 + G.cell / 2) & (np.abs(v) <= 0.2 + G.cell / 2)
    if np.isnan(t[covered]).any():
        assert r.verdict == "unknown"
    else:
        assert r.verdict == "ok"
