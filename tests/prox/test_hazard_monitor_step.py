"""The hazard monitor's per-cycle step on synthetic point clouds with known geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest

from prox_workflows.algorithms import hazard_monitor as hm

FRONT = 0.51 / 2


def ground(x0: float = 0.5, x1: float = 3.0, y0: float = -1.2, y1: float = 1.2, step: float = 0.02,
           noise: float = 0.003, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    X, Y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    return np.column_stack([X.ravel(), Y.ravel(), rng.normal(0.0, noise, X.size)])


def box(cx: float, cy: float, half: float = 0.1, height: float = 0.2, step: float = 0.01) -> np.ndarray:
    """The top and all four sides of an upright box, sampled densely."""
    a = np.arange(-half, half + 1e-9, step)
    zs = np.arange(0.0, height + 1e-9, step)
    top = np.array([(cx + u, cy + v, height) for u in a for v in a])
    sides = [np.array([(cx + s * half, cy + u, z) for u in a for z in zs]) for s in (-1, 1)]
    sides += [np.array([(cx + u, cy + s * half, z) for u in a for z in zs]) for s in (-1, 1)]
    return np.vstack([top, *sides])


def without(points: np.ndarray, cx: float, cy: float, half: float) -> np.ndarray:
    """The ground with the box's footprint cut out (the box stands there)."""
    keep = (np.abs(points[:, 0] - cx) > half) | (np.abs(points[:, 1] - cy) > half)
    return points[keep]


def test_flat_ground_is_clear_and_the_blind_zone_is_measured() -> None:
    p = hm.MonitorParams()
    check = hm.check_corridor(ground(x0=1.0), p)
    assert check.distance is None and check.hazard_cells == 0
    assert check.observed > 0.6
    # the first observed cell's near edge lies within one cell of where the points begin
    assert 1.0 - FRONT - p.cell <= check.blind <= 1.0 - FRONT + p.cell


@pytest.mark.parametrize("bx,by", [(1.5, 0.0), (2.0, 0.2), (1.2, -0.25)])
def test_an_obstacle_in_the_corridor_is_found_at_its_distance_and_bearing(bx: float, by: float) -> None:
    p = hm.MonitorParams(width=0.6)
    pts = np.vstack([without(ground(), bx, by, 0.1), box(bx, by)])
    check = hm.check_corridor(pts, p)
    true_gap = bx - 0.1 - FRONT
    assert check.distance is not None
    # conservative: never farther than the box, closer by at most the step window's half plus a cell
    assert true_gap - (p.hazard_params().window / 2 + 2 * p.cell) <= check.distance <= true_gap + 1e-9
    assert check.bearing == pytest.approx(math.degrees(math.atan2(check.y, check.x)))
    assert abs(check.y - by) <= 0.1 + p.hazard_params().window / 2 + p.cell


def test_an_obstacle_beside_the_corridor_is_not_in_it_but_is_when_the_corridor_turns() -> None:
    pts = np.vstack([without(ground(y1=2.0), 1.5, 1.0, 0.1), box(1.5, 1.0)])
    ahead = hm.check_corridor(pts, hm.MonitorParams(width=0.6))
    assert ahead.distance is None
    # moving towards 34 degrees left, the box (at 33.7 degrees from the centre) is in the way
    turned = hm.check_corridor(pts, hm.MonitorParams(width=0.6, heading=math.degrees(math.atan2(1.0, 1.5))))
    assert turned.distance is not None and turned.bearing == pytest.approx(33.7, abs=8.0)


def test_a_low_bump_is_not_a_hazard() -> None:
    pts = np.vstack([without(ground(), 1.5, 0.0, 0.1), box(1.5, 0.0, height=0.05)])
    check = hm.check_corridor(pts, hm.MonitorParams(hazard={"slope_max": 89.0}))
    assert check.distance is None


def test_no_points_means_nothing_observed() -> None:
    check = hm.check_corridor(np.zeros((0, 3)), hm.MonitorParams())
    assert check.distance is None and check.observed == 0.0


def test_level_tracker_looks_ahead_by_the_closing_speed() -> None:
    p = hm.MonitorParams(stop_distance=0.5, warn_distance=1.0)
    tracker = hm.LevelTracker(p)
    levels = []
    for k in range(25):  # closing at 0.8 m/s, a reading every 0.1 s, the next verdict 0.3 s later
        d = 1.6 - 0.08 * k
        levels.append((d, *tracker.update(d, 0.1 * k, lead=0.3)))
    first_stop = next(d for d, level, _ in levels if level == "stop")
    assert first_stop == pytest.approx(0.74, abs=0.05)  # 0.5 + 0.8 m/s x 0.3 s
    first_warn = next(d for d, level, _ in levels if level == "warning")
    assert first_warn == pytest.approx(1.24, abs=0.05)
    assert tracker.speed == pytest.approx(0.8, abs=0.05)


def test_level_tracker_takes_a_known_speed_and_is_not_fooled_by_one_jump() -> None:
    p = hm.MonitorParams(stop_distance=0.5, warn_distance=1.0)
    told = hm.LevelTracker(p)
    assert told.update(1.2, 0.0, lead=0.5, speed=0.6)[0] == "warning"  # 1.2 - 0.3 <= 1.0
    # standing still, a nearer cell turns up once (noise at the view's edge): no stop from it
    still = hm.LevelTracker(p)
    for k in range(5):
        still.update(1.5, 0.1 * k, lead=0.3)
    level, _ = still.update(1.3, 0.5, lead=0.3)
    assert level == "clear" and still.speed == 0.0


def test_level_tracker_hysteresis_and_clear() -> None:
    tracker = hm.LevelTracker(hm.MonitorParams(stop_distance=0.5, warn_distance=1.0, hysteresis=0.1))
    assert tracker.update(0.45, 0.0, 0.0)[0] == "stop"
    assert tracker.update(0.55, 1.0, 0.0)[0] == "stop"  # not yet past 0.5 + 0.1
    assert tracker.update(0.65, 2.0, 0.0)[0] == "warning"
    assert tracker.update(1.05, 3.0, 0.0)[0] == "warning"
    assert tracker.update(1.2, 4.0, 0.0)[0] == "clear"
    tracker.update(0.4, 5.0, 0.0)
    assert tracker.update(None, 6.0, 0.0)[0] == "clear"  # the hazard left the corridor


def test_memory_keeps_a_hazard_that_drove_into_the_blind_zone() -> None:
    p = hm.MonitorParams()
    memory = hm.HazardMemory(p.cell)
    seen = hm.check_corridor(np.vstack([without(ground(), 1.2, 0.0, 0.1), box(1.2, 0.0)]), p)
    memory.update(seen, (0.0, 0.0, 0.0))
    d0 = memory.nearest((0.0, 0.0, 0.0), p)
    assert d0 is not None and d0[0] == pytest.approx(seen.distance, abs=1e-9)
    # The rover drove 0.6 m on (the GNC's pose says so): the box is now below the view, which
    # starts 0.5 m ahead and sees only floor; the remembered box is 0.6 m closer.
    later = hm.check_corridor(ground(x0=0.5), p)
    assert later.distance is None
    memory.update(later, (0.6, 0.0, 0.0))
    d1 = memory.nearest((0.6, 0.0, 0.0), p)
    assert d1 is not None and d1[0] == pytest.approx(max(0.0, d0[0] - 0.6), abs=1e-6)
    # Turning left by 90 degrees takes it out of the corridor.
    assert memory.nearest((0.6, 0.0, 90.0), p) is None


def test_memory_forgets_a_hazard_seen_safe_again() -> None:
    p = hm.MonitorParams()
    memory = hm.HazardMemory(p.cell)
    memory.update(hm.check_corridor(np.vstack([without(ground(), 1.8, 0.0, 0.1), box(1.8, 0.0)]), p),
                  (0.0, 0.0, 0.0))
    assert memory.nearest((0.0, 0.0, 0.0), p) is not None
    memory.update(hm.check_corridor(ground(), p), (0.0, 0.0, 0.0))  # it has gone (or was a ghost)
    assert memory.nearest((0.0, 0.0, 0.0), p) is None


def test_rover_points_subsamples_and_drops_undefined_and_far_pixels() -> None:
    xyz = np.full((4, 6, 3), -1.0, np.float32)
    xyz[0, 0] = (0.0, 0.0, 1.0)
    xyz[2, 2] = (0.1, 0.2, 2.0)
    xyz[2, 4] = (0.0, 0.0, 9.0)  # beyond max_range
    xyz[1, 1] = (0.0, 0.0, 1.5)  # not on the subsampling grid
    T = np.eye(4)
    T[:3, 3] = (1.0, 0.0, 0.5)
    pts = hm.rover_points(xyz, T, subsample=2, max_range=4.5)
    assert pts.shape == (2, 3)
    np.testing.assert_allclose(pts[1], (1.1, 0.2, 2.5), atol=1e-6)


def test_params_are_checked() -> None:
    with pytest.raises(ValueError):
        hm.MonitorParams(stop_distance=2.0, warn_distance=1.0)
    with pytest.raises(ValueError):
        hm.MonitorParams(width=0.0)
    assert hm.MonitorParams(cell=0.2).hazard_params().window == pytest.approx(0.6)
