"""Map verdicts merge conservatively: a later "safe" from a partly seen hazard window never erases
a "hazardous". Dem2Hazard judges a window from its seen cells alone, so a view that caught only
the flat half of a rock's window calls the cell safe; the scan's or the memory's hazard there
must stand. A wholly seen window is a real second look and stands either way (the scan's false
hazards at 4.5 m must still be clearable from closer)."""

from __future__ import annotations

import numpy as np

from prox_workflows.algorithms.dem2hazard import HazardParams
from prox_workflows.algorithms.planner import NavMaps
from prox_workflows.algorithms.rolling_map import (
    MapMemory,
    RollingMap,
    RollingParams,
    merge_nav_maps,
    whole_windows,
)
from prox_workflows.grid import GridGeometry
from rvs_params.hazard import HAZARDOUS, SAFE, UNDEFINED

ROCK = (1.5, 0.0)


def _ground(rng: np.random.Generator, x0: float, x1: float, y0: float, y1: float, rock: bool) -> np.ndarray:
    """Dense points on flat ground over the box, with the 0.25 m tall, 0.2 m wide rock if ``rock``."""
    n = int(4000 * (x1 - x0) * (y1 - y0)) + 1
    x, y = rng.uniform(x0, x1, n), rng.uniform(y0, y1, n)
    z = 0.005 * rng.standard_normal(n)
    if rock:
        z += np.where(np.hypot(x - ROCK[0], y - ROCK[1]) < 0.1, 0.25, 0.0)
    return np.column_stack([x, y, z])


def test_whole_windows_needs_every_cell_of_the_window() -> None:
    dem = np.zeros((9, 9))
    dem[4, 6] = np.nan
    whole = whole_windows(dem, 3)
    assert not whole[0].any() and not whole[:, 0].any()  # the window reaches off the grid
    assert not whole[3:6, 5:8].any()  # the hole is in their windows
    assert whole[4, 4] and whole[2, 6] and whole[6, 6]


def test_a_partly_seen_safe_never_erases_a_hazard_in_the_merge() -> None:
    g = GridGeometry(0.05, 0.0, 1.0, 20, 20)
    scan = NavMaps(np.full(g.shape, HAZARDOUS, np.uint8), np.zeros(g.shape, np.float32), g)
    whole = np.zeros(g.shape, bool)
    whole[:, :10] = True  # the rolling map saw the west half's windows wholly
    fresh = NavMaps(np.full(g.shape, SAFE, np.uint8), np.zeros(g.shape, np.float32), g, whole)
    merged = merge_nav_maps(scan, fresh).hazard
    assert (merged[:, :10] == SAFE).all()  # a real second look clears the scan's hazard
    assert (merged[:, 10:] == HAZARDOUS).all()  # a glimpse does not
    # a hazard the rolling map saw partly still adds to a safe scan
    rolling = NavMaps(np.full(g.shape, HAZARDOUS, np.uint8), np.zeros(g.shape, np.float32), g,
                      np.zeros(g.shape, bool))
    safe_scan = NavMaps(np.full(g.shape, SAFE, np.uint8), np.zeros(g.shape, np.float32), g)
    assert (merge_nav_maps(safe_scan, rolling).hazard == HAZARDOUS).all()
    # where the rolling map saw nothing the scan stands
    unseen = NavMaps(np.full(g.shape, UNDEFINED, np.uint8), np.zeros(g.shape, np.float32), g, whole)
    assert (merge_nav_maps(scan, unseen).hazard == HAZARDOUS).all()


def test_the_memory_keeps_a_rock_a_later_glimpse_calls_safe() -> None:
    """The rolling map sees the rock wholly; the map scrolls away and back (heights lost), and a
    new view catches only the strip west of the rock's centre: its windows over the rock cell are
    half seen and flat, so it calls them safe. The memory keeps the rock; a later whole view of
    flat ground (the rock gone, as a wrong first look would be) clears it."""
    rng = np.random.default_rng(5)
    params = HazardParams()
    memory = MapMemory(GridGeometry(0.05, -2.0, 2.0, 80, 80))
    first = RollingMap(RollingParams(size=4.0), params, (0.0, 0.0), memory)
    first.fuse(_ground(rng, 0.5, 2.5, -1.0, 1.0, rock=True))
    first.remember()
    r, c = memory.geometry.cell_of(np.array([ROCK[0]]), np.array([ROCK[1]]))
    rock = (int(r[0]), int(c[0]))
    assert memory.hazard[rock] == HAZARDOUS

    before = memory.hazard.copy()
    glimpse = RollingMap(RollingParams(size=4.0), params, (0.0, 0.0), memory)
    glimpse.fuse(_ground(rng, 0.5, ROCK[0] - 0.12, -1.0, 1.0, rock=False))
    glimpse.remember()
    # the glimpse's cells on the memory's grid (both on one lattice, the same origin here)
    glimpsed_safe = (glimpse.stamp > 0) & (glimpse.hazard == SAFE) & ~glimpse.whole
    rows, cols = np.nonzero(glimpsed_safe)
    xs, ys = glimpse.geometry.centers()
    mr, mc = memory.geometry.cell_of(xs[cols], ys[rows])
    was_rock = before[mr, mc] == HAZARDOUS
    assert was_rock.sum() >= 5  # the glimpse called safe some cells the memory holds a rock in
    assert (memory.hazard[mr[was_rock], mc[was_rock]] == HAZARDOUS).all()
    assert memory.hazard[rock] == HAZARDOUS

    second = RollingMap(RollingParams(size=4.0), params, (0.0, 0.0), memory)
    second.fuse(_ground(rng, 0.5, 2.5, -1.0, 1.0, rock=False))
    second.remember()
    assert memory.hazard[rock] == SAFE and memory.whole[rock]
