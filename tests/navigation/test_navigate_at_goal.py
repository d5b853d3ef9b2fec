"""navigate to a goal the rover already stands on: nothing to drive, OK with the usual products,
also on a fresh server that has no map yet (the traverse figure is then drawn on unknown ground)."""

from __future__ import annotations

import csv

import pytest


@pytest.mark.parametrize("loop", ["scan", "see"])
def test_navigate_to_where_the_rover_stands_is_ok_with_nothing_to_do(server, loop: str) -> None:
    c = server.client()
    assert server.app.maps.layers is None  # a fresh server: no DEM yet
    r = c.request(f"navigate -goal 0,0 -loop {loop} -name here")
    assert r.status == "OK", r.fields
    assert r.fields["reached"] == "true" and r.fields["legs"] == "0"
    assert (r.fields["x"], r.fields["y"]) == ("0.000", "0.000")
    assert r.fields["path"] == "nav/here_traverse.png"
    assert (server.data / r.fields["path"]).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (server.data / r.fields["waypoints"]).read_text() == "x,y,leg\n"  # no leg, no waypoint
    with open(server.data / r.fields["track"]) as fh:
        assert [(row["x"], row["y"]) for row in csv.DictReader(fh)] == [("0.0000", "0.0000")]
    assert c.request("status").fields["mode"] == "ready"


def test_navigate_within_tolerance_of_the_goal_is_ok_without_a_scan(server) -> None:
    c = server.client()
    r = c.request("navigate -start 0.1,-0.1,30 -goal 0,0 -tolerance 0.3 -name near")
    assert r.status == "OK", r.fields
    assert r.fields["legs"] == "0" and (r.fields["x"], r.fields["y"]) == ("0.100", "-0.100")
    assert (server.data / "nav/near_traverse.png").stat().st_size > 0
