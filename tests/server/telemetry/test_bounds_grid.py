"""The see loop's bounds map in recordings and on Foxglove: a Grid of the lower and upper bound
per cell over the cells that have one, sent when a plan reads the map and every tenth frame
fused into it, latched (a recording started later takes it as it is then); the gate's stops go
out as wire lines, warnings on /rvs/log. A short see-loop navigate records it end to end."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from foxglove.messages import LogLevel
from support.marks import long_test
from support.mcap import decoded, grid_fields

from prox_workflows.algorithms.bounds_map import BoundsMap
from rvs_server.protocol import Reply
from rvs_server.telemetry.hub import BOUNDS_EVERY


def look(bounds: BoundsMap, x0: float, rock: float) -> None:
    """One frame of flat ground from x0 to x0 + 1 m, a rock ``rock`` m high at its middle,
    seen from a sensor a metre up behind it."""
    rng = np.random.default_rng(int(x0 * 10))
    xy = np.c_[rng.uniform(x0, x0 + 1.0, 40000), rng.uniform(-0.5, 0.5, 40000)]
    z = np.where(np.hypot(xy[:, 0] - x0 - 0.5, xy[:, 1]) < 0.08, rock, 0.0) + rng.normal(0, 0.003, len(xy))
    bounds.fuse(np.c_[xy, z], 0.003, np.array([x0 - 0.5, 0.0, 1.0]), 3.0)


def placed(grid: Any, bounds: BoundsMap) -> dict[str, np.ndarray]:
    """The grid's fields laid into the bounds map's whole grid (NaN elsewhere), by its origin
    and cell size: what an operator's Foxglove draws where it draws it."""
    g = bounds.geometry
    assert grid.frame_id == "world" and grid.cell_size.x == grid.cell_size.y == g.cell
    fields = grid_fields(grid)
    rows, cols = next(iter(fields.values())).shape
    c0 = round((grid.pose.position.x - g.xmin) / g.cell)
    r0 = round((g.ymax - grid.pose.position.y) / g.cell) - rows  # the origin is the south-west corner
    assert 0 <= c0 and c0 + cols <= g.width and 0 <= r0 and r0 + rows <= g.height
    out = {}
    for name, values in fields.items():
        whole = np.full(g.shape, np.nan, np.float32)
        whole[r0:r0 + rows, c0:c0 + cols] = values
        out[name] = whole
    return out


def test_the_bounds_map_is_a_latched_grid_sent_at_each_plan_and_every_tenth_frame(server_factory: Any) -> None:
    srv = server_factory()
    app, c = srv.app, srv.client()
    bounds = BoundsMap.covering([(0.0, 0.0), (3.0, 0.0)], 1.0)
    states: list[tuple[np.ndarray, np.ndarray]] = []  # the map's bounds at each send expected

    look(bounds, 0.0, 0.12)
    app.bus.publish("bounds", bounds=bounds)  # nobody listens: the hub keeps the map
    states.append((bounds.lower, bounds.upper))
    assert c.request("record -start -name gate").status == "OK"  # ...and the recording takes it at its start
    assert app.telemetry.hub.drained().wait(10)  # (read in the hub's thread: the next frame waits for it here)
    look(bounds, 1.0, 0.05)
    app.bus.publish("bounds", bounds=bounds, replan=True)  # a plan read it: sent
    states.append((bounds.lower, bounds.upper))
    for i in range(3, BOUNDS_EVERY + 2):  # frames, the map's 3rd to 11th publication: only the 10th is sent
        look(bounds, 0.1 * i, 0.0)
        app.bus.publish("bounds", bounds=bounds)
        if i == BOUNDS_EVERY:
            states.append((bounds.lower, bounds.upper))
    # the gate's stop, as the see loop broadcasts it
    app.broadcast_threadsafe(Reply("RVS", "EVENT", {"kind": "hazard", "level": "stop", "reason": "vehicle",
                                                    "distance": 0.4, "job": 1, "source": "navigate"}))
    assert c.request("record -stop").fields["dropped"] == "0"

    messages = decoded(srv.data / "recordings" / "gate.mcap")
    grids = [m for topic, _, m in messages if topic == "/nav/bounds"]
    assert len(grids) == len(states)
    for grid, (lower, upper) in zip(grids, states, strict=True):
        assert [f.name for f in grid.fields] == ["lower", "upper"]
        got = placed(grid, bounds)
        np.testing.assert_array_equal(got["lower"], lower)  # every bound, NaN (none) outside the box sent
        np.testing.assert_array_equal(got["upper"], upper)
    # the rock of the first look stands in its upper bound, the ground round it does not
    g = bounds.geometry
    top = placed(grids[0], bounds)["upper"]
    r, c_ = g.cell_of(np.array([0.5]), np.array([0.0]))
    assert top[r[0], c_[0]] > 0.11 and np.nanmedian(top) < 0.03
    assert grids[0].cell_size.x == 0.025 and math.isnan(top[0, 0])
    # the stop on /rvs/log: a warning from the event stream
    stops = [m for topic, _, m in messages if topic == "/rvs/log" and "reason=vehicle" in m.message]
    assert len(stops) == 1 and stops[0].level == LogLevel.Warning.value and stops[0].name == "event"


@long_test
def test_a_see_loop_navigate_records_its_bounds_map(server_factory: Any) -> None:
    """The quarry mission of tests/navigation/test_vehicle_gate.py (about 15 s), recorded: the
    bounds grid at each replan and as the frames come, the last one bounding the driven way."""
    srv = server_factory(["server.scene=quarry", "navigate.range=-30,30,-50,-10", "navigate.see_gate=bounds"])
    srv.app.world.set_target_visible(False)
    c = srv.client()
    assert c.request("record -start -name nav").status == "OK"
    job = c.start_job("navigate -start 0,0,0 -goal 3.2,0 -auto -loop see -name gate")
    final = c.until_final(job=job, timeout=900)[-1]
    assert final.status == "OK" and final.fields["reached"] == "true", final.fields
    assert c.request("record -stop").fields["dropped"] == "0"
    messages = decoded(srv.data / "recordings" / "nav.mcap")
    grids = [m for topic, _, m in messages if topic == "/nav/bounds"]
    frames = sum(1 for topic, _, m in messages if topic == "/raw/calls" and m["call"] == "grab_xyz")
    assert len(grids) >= max(int(final.fields["replans"]), frames // BOUNDS_EVERY), (len(grids), frames)
    upper = grid_fields(grids[-1])["upper"]
    g = grids[-1]
    xs = g.pose.position.x + (np.arange(g.column_count) + 0.5) * g.cell_size.x
    assert xs[0] < 0.5 and xs[-1] > 3.2  # the way from the start to the goal
    assert np.isfinite(upper).mean() > 0.3
