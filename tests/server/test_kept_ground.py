"""What the server keeps of the rover's travel between jobs (rvs_server.travel): the bounds map the
last navigate left, taken by the next one only where the rover still stands and the settings that
made it are the same."""

from __future__ import annotations

from rvs_server.travel import STILL_HEADING, STILL_XY, KeptGround, Travel

MAP = object()  # a bounds map as the keeper sees it: a thing handed on, never read
KEY = ("bounds params", 3.5, "ring")


def kept(pose: tuple[float, float, float] = (1.0, 2.0, 179.0)) -> Travel:
    travel = Travel()
    travel.leave(KeptGround(MAP, pose, KEY))
    return travel


def test_the_next_navigate_where_the_rover_still_stands_takes_the_map_once() -> None:
    travel = kept()
    # within the tolerances, the heading across the +-180 seam
    assert travel.take((1.0 + 0.8 * STILL_XY, 2.0, -179.0 - 0.4 * STILL_HEADING), KEY) is MAP
    assert travel.take((1.0, 2.0, 179.0), KEY) is None  # taken: two jobs never share one map


def test_a_rover_that_moved_or_a_map_made_otherwise_starts_fresh() -> None:
    assert kept().take((1.0 + 1.5 * STILL_XY, 2.0, 179.0), KEY) is None
    assert kept().take((1.0, 2.0, 179.0 - 1.5 * STILL_HEADING), KEY) is None
    assert kept().take((1.0, 2.0, 179.0), ("other params", 3.5, "ring")) is None
    carried = kept()
    carried.forget()  # sim move-rover, another scene
    assert carried.take((1.0, 2.0, 179.0), KEY) is None
