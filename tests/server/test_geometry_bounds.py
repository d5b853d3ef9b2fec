"""Geometry that a request can make arbitrarily large: check-move's sweep and navigate's plans.

Every value the help accepts either answers or is refused with the limit before any work (and
before a job's ACK); none blocks the event loop or ends in E_INTERNAL.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest
from support.server import ServerThread

from prox_workflows.algorithms.plan_maps import MAX_PLAN_CELLS
from prox_workflows.algorithms.safety import MAX_SWEEP_CELLS
from prox_workflows.grid import GridGeometry, Layers
from rvs_server.commands import navigation

# a 10 m x 10 m map of 5 cm cells, all drivable, around the rover at the origin
G = GridGeometry(0.05, -5.0, 5.0, 200, 200)


@pytest.fixture
def mapped(server: ServerThread) -> ServerThread:
    trav = np.full(G.shape, 0.9, np.float32)
    server.app.maps.replace(Layers(G, {"dem": np.zeros(G.shape, np.float32), "traversability": trav}), "flat", {})
    return server


def test_check_move_answers_at_its_documented_extremes(mapped: ServerThread) -> None:
    c = mapped.client()
    # the help's bounds: -dx/-dy in [-50, 50] m, -dyaw in [-360, 360] deg
    far = c.request("check-move -dx 50 -dy 50")
    assert far.status == "OK" and far.fields["verdict"] == "unknown"  # it leaves the 10 m map
    assert int(far.fields["unknown_cells"]) > 0 and int(far.fields["blocked_cells"]) == 0
    turn = c.request("check-move -dyaw 360")
    assert turn.status == "OK" and turn.fields["verdict"] == "ok"
    within = c.request("check-move -to 150,150")  # a 9-million-cell box: answered, not refused
    assert within.status == "OK" and within.fields["verdict"] == "unknown"
    # inside the help's +-1e6, but 4e14 cells: refused with the limit, not a MemoryError
    huge = c.request("check-move -to 1e6,1e6")
    assert huge.fields["code"] == "E_ARG"
    assert f"{MAX_SWEEP_CELLS:,}" in huge.fields["message"] and "shorter move" in huge.fields["message"]
    assert c.request("status").status == "OK"


def test_check_move_runs_off_the_event_loop(mapped: ServerThread, monkeypatch: pytest.MonkeyPatch) -> None:
    """While a check computes, status on another connection is answered."""
    computing, release = threading.Event(), threading.Event()
    real = navigation.check_move
    answered_meanwhile: list[bool] = []

    def slow(*args: object, **kw: object) -> object:
        computing.set()
        answered_meanwhile.append(release.wait(30))  # released by the test once status answered
        return real(*args, **kw)

    monkeypatch.setattr(navigation, "check_move", slow)
    a, b = mapped.client(), mapped.client()
    a.send("check-move -dx 1")
    assert computing.wait(30)
    assert b.request("status", timeout=10).status == "OK"  # on the event loop, the check would hold this
    release.set()
    assert a.until_final()[-1].fields["verdict"] == "ok"
    assert answered_meanwhile == [True]


def test_navigate_refuses_a_goal_beyond_its_plans_before_the_ack(server: ServerThread) -> None:
    c = server.client()
    r = c.request("navigate -goal 1e6,1e6 -auto")
    assert r.status == "ERROR" and r.fields["code"] == "E_ARG"  # the final line, with no ACK before it
    assert f"{MAX_PLAN_CELLS:,}" in r.fields["message"] and "nearer goal" in r.fields["message"]
    assert "job" not in r.fields
    assert c.request("status").fields["mode"] == "ready"


def test_an_inverted_view_range_is_refused_before_the_ack_and_leaves_no_folder(server: ServerThread) -> None:
    c = server.client()
    for line in ("dem-full-tof -range 90,-90,-45,-10 -name inv", "dem-full -range -90,90,-10,-45 -name inv",
                 "track3d-detect -range 90,-90,-20,0"):
        r = c.request(line)
        assert r.status == "ERROR" and r.fields["code"] == "E_ARG" and "job" not in r.fields, line
        assert "inverted" in r.fields["message"] and "-range" in r.fields["message"]
    assert not list(server.data.rglob("inv_views"))
    bad = c.request("config -module dem-full-tof -set range=10,-10,-40,-20")
    assert bad.fields["code"] == "E_ARG" and "inverted" in bad.fields["message"]
