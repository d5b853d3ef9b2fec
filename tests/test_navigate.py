"""navigate with the simulated rover driving itself (-auto): reaches the goal on quarry and
marsyard from seeded starts, and the rover's true track never crosses a true hazard. (One start
per scene in the default suite, three with RVS_LONG=1: each is 10-15 s of CPU.)"""

from __future__ import annotations

import csv

import numpy as np
import pytest
from conftest import long_only
from scipy import ndimage

from drivers.sim.world import World
from prox_workflows.grid import GridGeometry
from prox_workflows.steps.dem2hazard import HazardParams, dem2hazard

AREA = {"quarry": (-3.0, -4.0, 7.0, 4.0), "marsyard": (-4.0, -6.0, 8.0, 6.0)}


def true_hazard(world: World, bounds) -> tuple[np.ndarray, GridGeometry]:
    g = GridGeometry.covering(*bounds, 0.05)
    dem = world.true_dem(g.cell, g.bounds, include_target=False)
    return dem2hazard(dem, g.cell, HazardParams())["hazard"], g


def pick_start_goal(world: World, scene: str, seed: int) -> tuple[tuple[float, float], tuple[float, float]]:
    """A start and a goal 3.5-5 m apart, both at least 1 m from any true hazard."""
    hazard, g = true_hazard(world, AREA[scene])
    clear = ndimage.distance_transform_edt(hazard != 255) * g.cell >= 1.0
    clear &= hazard == 0
    rows, cols = np.nonzero(clear)
    xs, ys = g.centers()
    rng = np.random.default_rng(seed)
    for _ in range(1000):
        i, j = rng.integers(len(rows), size=2)
        s = (float(xs[cols[i]]), float(ys[rows[i]]))
        e = (float(xs[cols[j]]), float(ys[rows[j]]))
        if 3.5 <= np.hypot(e[0] - s[0], e[1] - s[1]) <= 5.0:
            return s, e
    raise AssertionError("no start/goal pair found")


@pytest.mark.parametrize("scene", ["quarry", "marsyard"])
@pytest.mark.parametrize("seed", [1, pytest.param(2, marks=long_only()), pytest.param(3, marks=long_only())])
def test_navigate_reaches_the_goal_without_crossing_a_hazard(server_factory, scene: str, seed: int) -> None:
    srv = server_factory([f"server.scene={scene}"])
    world = srv.app.world
    world.set_target_visible(False)  # the walking astronaut is not terrain
    start, goal = pick_start_goal(world, scene, seed)
    c = srv.client()
    heading = float(np.degrees(np.arctan2(goal[1] - start[1], goal[0] - start[0])))
    r = c.request(f"navigate -start {start[0]:.3f},{start[1]:.3f},{heading:.1f} "
                  f"-goal {goal[0]:.3f},{goal[1]:.3f} -auto -name run", timeout=600)
    assert r.status == "OK", r.fields
    truth = world.truth()
    assert np.hypot(truth["x"] - goal[0], truth["y"] - goal[1]) <= 0.3
    assert r.fields["reached"] == "true" and int(r.fields["legs"]) >= 1
    with open(srv.data / r.fields["track"]) as fh:
        track = np.array([[float(row["x"]), float(row["y"])] for row in csv.DictReader(fh)])
    assert len(track) > 10
    hazard, g = true_hazard(world, AREA[scene])
    rr, cc = g.cell_of(track[:, 0], track[:, 1])
    assert g.inside(rr, cc).all()
    assert not (hazard[rr, cc] == 255).any(), "the rover's true track crossed a true hazard"
    assert (srv.data / r.fields["path"]).stat().st_size > 1000


def test_navigate_waits_for_the_gnc_pose(server_factory) -> None:
    srv = server_factory(["server.scene=office"])
    c, gnc = srv.client(), srv.client()
    job = c.start_job("navigate -goal 1.5,-1.2 -name wait")
    event = None
    while event is None:
        line = gnc.reply(timeout=120)
        if line.status == "EVENT" and line.fields.get("kind") == "waiting":
            event = line
    assert event.fields["job"] == job and event.fields["leg"] == "1"
    wps = [float(v) for v in event.fields["waypoints"].split(",")]
    assert len(wps) % 3 == 0  # x, y, heading per waypoint
    end = wps[-3:-1]
    # the GNC drives the rover (here: the simulator) and reports where it is
    srv.app.world.set_rover_pose(end[0], end[1], 0.0)
    assert gnc.request(f"pose -x {end[0]} -y {end[1]} -heading 0").status == "OK"
    final = c.until_final(job=job, timeout=300)[-1]
    assert final.status == "OK" and final.fields["reached"] == "true", final.fields


def test_navigate_errors(server_factory) -> None:
    srv = server_factory(["server.scene=office"])
    c = srv.client()
    assert c.request("navigate").fields["code"] == "E_ARG"  # -goal is required
    r = c.request("navigate -goal 2.3,-0.45 -auto", timeout=300)  # on the tall rock
    assert r.fields["code"] == "E_DATA" and "goal_in_hazard" in r.fields["message"]
    r = c.request("navigate -goal 40,0 -auto", timeout=300)  # far outside any map: blank maps, then no progress
    assert r.status == "ERROR" and r.fields["code"] == "E_DATA"


def test_navigate_with_the_fused_sensor(server_factory) -> None:
    srv = server_factory(["server.scene=office"])
    c = srv.client()
    r = c.request("navigate -goal 1.6,-1.3 -sensor fused -auto -name fused", timeout=600)
    assert r.status == "OK" and r.fields["reached"] == "true", r.fields
    truth = srv.app.world.truth()
    assert np.hypot(truth["x"] - 1.6, truth["y"] + 1.3) <= 0.3
