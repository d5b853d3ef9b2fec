"""The see loop's bounds map is a window that follows the rover: the cells that stay inside
keep what they hold, bit for bit what a map over the whole mission holds there; the cells it
leaves are dropped (ground it comes back to is unknown again); its size does not grow with the
distance driven. A pose fix moves what the frames since the last fix placed by the fix. The
chooser's coarse guidance keeps the whole mission at 25 cm: a wall the window left stays a wall."""

from __future__ import annotations

import numpy as np

from drivers.sim.rover import RoverBody
from prox_workflows.algorithms.bounds_map import BoundsMap
from prox_workflows.algorithms.coarse_memory import CoarseMemory

SENSOR_Z = 1.2


def _rock_frame(x: float, y: float, rock: float = 0.2, half: float = 1.0) -> np.ndarray:
    """Every centimetre of level ground (z 0) within ``half`` m of (x, y), with a 0.2 x 0.2 m
    block ``rock`` high at its centre."""
    gx, gy = np.meshgrid(np.arange(x - half, x + half, 0.01) + 0.005,
                         np.arange(y - half, y + half, 0.01) + 0.005)
    gx, gy = gx.ravel(), gy.ravel()
    z = np.where((np.abs(gx - x) < 0.1) & (np.abs(gy - y) < 0.1), rock, 0.0)
    return np.column_stack([gx, gy, z])


def _fuse(m: BoundsMap, pts: np.ndarray, at: tuple[float, float]) -> None:
    m.fuse(pts, 0.003, np.array([at[0], at[1], SENSOR_Z]))


def _upper_at(m: BoundsMap, x: float, y: float) -> float:
    lower, upper, _ = m.window(x - 0.001, y - 0.001, x + 0.001, y + 0.001)
    return float(upper[0, 0]) if upper.size else float("nan")


def test_a_window_keeps_what_stays_inside_as_the_whole_mission_map_holds_it_and_drops_the_rest() -> None:
    whole = BoundsMap.covering([(0.0, -5.0), (30.0, 5.0)], 0.0)
    window = BoundsMap.around((2.0, 0.0), 4.6, 0.25)
    g0 = window.geometry
    assert g0.width == g0.height == 370 and g0.xmin % 0.25 == 0 and g0.ymax % 0.25 == 0
    rock = _rock_frame(4.0, 0.5)
    for m in (whole, window):
        _fuse(m, rock, (2.0, 0.0))
    assert _upper_at(window, 4.0, 0.5) > 0.19
    # the rover drives on 1.5 m: the window recentres, the rock stays inside with all it held
    assert not window.follow(2.9, 0.0, 1.0)
    assert window.follow(3.5, 0.0, 1.0)
    g1 = window.geometry
    assert (g1.xmin - g0.xmin, g1.ymax - g0.ymax, g1.shape) == (1.5, 0.0, g0.shape)
    box = (2.8125, -0.5875, 5.2125, 1.6125)  # edges mid-cell: both grids cut it alike
    for a, b in zip(window.window(*box)[:2], whole.window(*box)[:2], strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    held = np.isfinite(window.window(*box)[1]).sum()
    assert held > 0.9 * 2.0 * 2.0 / 0.025**2  # the frame's 2 x 2 m
    # 10 m on, the rock's ground has left the window: dropped, unknown when the window comes back
    window.follow(14.0, 0.0, 1.0)
    assert np.isnan(_upper_at(window, 4.0, 0.5)) or window.geometry.xmin > 4.0
    window.follow(3.5, 0.0, 1.0)
    assert np.isnan(window.window(*box)[1]).all()
    assert _upper_at(whole, 4.0, 0.5) > 0.19  # (the fixed map keeps it)


def test_a_window_driven_200_m_holds_no_more_than_at_its_start() -> None:
    window = BoundsMap.around((0.0, 0.0), 4.6, 0.25)

    def held() -> int:
        return sum(a.nbytes for a in vars(window).values() if isinstance(a, np.ndarray))

    start = held()
    for x in np.arange(0.0, 200.0, 0.5):
        window.follow(float(x), 0.3 * np.sin(x / 7.0), 1.0)
        if x % 10 == 0 or x == 199.5:
            _fuse(window, _rock_frame(float(x) + 1.5, 0.0, 0.1), (float(x), 0.0))
    assert held() == start and window.geometry.shape == (370, 370)
    assert window.geometry.xmin > 190.0
    assert _upper_at(window, 201.0, 0.0) > 0.09  # the last frame's rock, where it was placed


def test_a_fix_moves_the_frames_since_the_last_fix_by_its_offset_and_leaves_the_earlier() -> None:
    m = BoundsMap.around((0.0, 0.0), 4.6, 0.25)
    _fuse(m, _rock_frame(-2.0, -2.0, half=0.5), (-1.0, -1.0))  # before the last fix: stays
    since = m.frames
    _fuse(m, _rock_frame(1.5, 0.5), (0.0, 0.0))  # placed with the pose the fix corrects
    earlier = m.window(-2.5, -2.5, -1.5, -1.5)[:2]
    before, _, g = m.window(1.0, 0.0, 2.0, 1.0)[1], None, m.geometry
    ceiling_before = m.ceiling.copy()
    dx, dy = 0.25, -0.1  # 10 and -4 cells
    m.move((0.0, 0.0), dx, dy, 0.0, since)
    after = m.window(1.0 + dx, 0.0 + dy, 2.0 + dx, 1.0 + dy)[1]
    assert np.array_equal(before, after, equal_nan=True)
    assert _upper_at(m, 1.5 + dx, 0.5 + dy) > 0.19 and _upper_at(m, 1.5 - 0.12, 0.5) < 0.05
    for a, b in zip(earlier, m.window(-2.5, -2.5, -1.5, -1.5)[:2], strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    # the frame's ray ceilings moved with it: 10 columns east, 4 rows south
    moved = m.lowered > since
    assert moved.sum() > 1000
    r, c = np.nonzero(moved)
    assert np.array_equal(m.ceiling[r, c], ceiling_before[r - 4, c - 10])
    assert g == m.geometry


def test_a_fix_that_turns_the_frame_turns_the_rock_about_the_pivot() -> None:
    m = BoundsMap.around((0.0, 0.0), 4.6, 0.25)
    _fuse(m, _rock_frame(2.0, 0.0), (0.0, 0.0))
    m.move((0.0, 0.0), 0.0, 0.0, 90.0, 0)
    assert _upper_at(m, 0.0, 2.0) > 0.19
    assert not _upper_at(m, 2.0, 0.0) > 0.05  # where it was: unknown (NaN), the frame moved away


def test_the_coarse_guidance_keeps_a_wall_the_window_left_and_sees_the_goal_200_m_on() -> None:
    body = RoverBody()
    guide = CoarseMemory.covering([(0.0, 0.0), (-200.0, 0.0)], 4.0)
    window = BoundsMap.around((0.0, 0.0), 4.6, 0.25)
    # a 0.5 m wall across the way west, 2 m ahead, 3 m wide: seen, then left behind eastward
    wall = _rock_frame(-2.0, 0.0, rock=0.0, half=2.0)
    wall[:, 2] = np.where((np.abs(wall[:, 0] + 2.0) < 0.2) & (np.abs(wall[:, 1]) < 1.5), 0.5, 0.0)
    _fuse(window, wall, (0.0, 0.0))
    guide.update(window.whole(), window.geometry, body)
    walled = guide.cost[guide.geometry.cell_of(-2.0, 0.0)]
    assert np.isinf(walled)
    window.follow(8.0, 0.0, 1.0)
    guide.update(window.whole(), window.geometry, body)
    assert np.isinf(guide.cost[guide.geometry.cell_of(-2.0, 0.0)])  # the window left it; the guide keeps it
    ctg = guide.cost_to_go((-200.0, 0.0))
    here = float(ctg.at(np.array([0.0]), np.array([0.0]))[0])
    assert 200.0 < here < 2.0 * 200.0 + 10.0  # the whole way to the goal, round the wall
    straight = float(ctg.at(np.array([-2.0]), np.array([2.0]))[0])
    assert np.isfinite(straight)
