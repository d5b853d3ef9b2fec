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
    ground = travel.take((1.0 + 0.8 * STILL_XY, 2.0, -179.0 - 0.4 * STILL_HEADING), KEY)
    assert ground is not None and ground.bounds is MAP and ground.still((1.0 + 0.8 * STILL_XY, 2.0, -179.4))
    assert travel.take((1.0, 2.0, 179.0), KEY) is None  # taken: two jobs never share one map


def test_a_rover_that_moved_or_a_map_made_otherwise_starts_fresh() -> None:
    assert kept().take((1.0 + 1.5 * STILL_XY, 2.0, 179.0), KEY) is None
    assert kept().take((1.0, 2.0, 179.0 - 1.5 * STILL_HEADING), KEY) is None
    assert kept().take((1.0, 2.0, 179.0), ("other params", 3.5, "ring")) is None
    carried = kept()
    carried.forget()  # sim move-rover, another scene
    assert carried.take((1.0, 2.0, 179.0), KEY) is None


def test_a_rover_the_gnc_moved_a_little_takes_the_map_to_be_set_down_on_again() -> None:
    """Backed 0.6 m out of where it was set down by the GNC's own drive, the rover takes the map
    whose frames saw the ground it now stands on (the navigate sets it down again there); 2.5 m
    away with 2 m allowed, or turned and moved with nothing allowed, it does not."""
    moved = (1.0 - 0.6, 2.0, 175.0)
    ground = kept().take(moved, KEY, within=2.0)
    assert ground is not None and ground.bounds is MAP
    assert not ground.still(moved) and abs(ground.moved(moved) - 0.6) < 1e-9
    assert kept().take((1.0 - 2.5, 2.0, 179.0), KEY, within=2.0) is None
    assert kept().take(moved, KEY) is None
    carried = kept()
    carried.forget()  # sim move-rover: carried off, not driven
    assert carried.take(moved, KEY, within=2.0) is None
