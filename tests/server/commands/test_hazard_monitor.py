"""hazard-start / hazard-stop through the server, against the simulator's truth.

The requirement: with the rover driven toward a rock, the stop event arrives before the
rover is within the configured stopping distance, in every one of 10 seeded runs; the cycle time
(PTU motion excluded) stays under 0.5 s. Plus the protocol rules: the monitor yields to jobs and
restores its pointing, break pauses it, one PTU holder at a time, device faults end it, and
shutdown stops its thread.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import pytest
from support.marks import long_test
from support.server import wait_for

STOP, WARN, WIDTH, ROVER_LENGTH = 0.5, 1.0, 0.6, 0.51
SPEED = 0.7  # m/s, the Pioneer 3-AT's top speed
PERIOD = 0.2  # s: the monitor's -period, and a frame of simulated time (a cycle on a busy machine)


def true_gap(world: Any, rock: dict[str, float], width: float = WIDTH) -> float:
    """Free run from the rover's front to the rock's footprint (its whole ellipse) inside the
    corridor, along the rover's heading: the strictest reading of 'within the stopping distance'."""
    x, y, h = world.rover_pose()
    t = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    c, s = math.cos(math.radians(rock["yaw"])), math.sin(math.radians(rock["yaw"]))
    ex, ey = rock["a"] * np.cos(t), rock["b"] * np.sin(t)
    px, py = rock["x"] + c * ex - s * ey, rock["y"] + s * ex + c * ey
    ch, sh = math.cos(math.radians(h)), math.sin(math.radians(h))
    u = (px - x) * ch + (py - y) * sh
    v = -(px - x) * sh + (py - y) * ch
    inside = (np.abs(v) <= width / 2) & (u > 0)
    return float(u[inside].min()) - ROVER_LENGTH / 2 if inside.any() else math.inf


def place(world: Any, rock: dict[str, float], gap: float, lateral: float, heading: float) -> None:
    """Put the rover ``gap`` in front of the rock (rock centre ``lateral`` off its axis)."""
    u = np.array([math.cos(math.radians(heading)), math.sin(math.radians(heading))])
    v = np.array([-u[1], u[0]])
    centre = np.array([rock["x"], rock["y"]])
    pos = centre - 3.0 * u - lateral * v
    world.set_rover_pose(pos[0], pos[1], heading)
    shift = true_gap(world, rock) - gap
    pos = pos + shift * u
    world.set_rover_pose(pos[0], pos[1], heading)


def next_event(client: Any, kind: str, timeout: float = 60.0) -> dict[str, str]:
    """The next EVENT of ``kind`` (the timeout is a safety net for a hang, not a speed bound)."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            raise AssertionError(f"no {kind} event within {timeout} s")
        r = client.reply(timeout=left)
        if r.status == "EVENT" and r.fields.get("kind") == kind:
            return r.fields


class Gnc:
    """Drives the simulated rover straight on at SPEED and reports its pose to the server as a
    GNC would, frame by frame in simulated time (tests/simtime.py): where the rover is when a
    frame is taken does not depend on how fast the machine is."""

    def __init__(self, app: Any, world: Any) -> None:
        self.app, self.world = app, world
        self.since: float | None = None  # simulated time of the last move; None: standing

    def drive(self, t: float) -> None:
        self.since = t

    def halt(self) -> None:
        self.since = None

    def on_frame(self, t: float) -> None:
        if self.since is not None:
            self.move(t)

    def move(self, t: float) -> None:
        self.world.move_rover(SPEED * (t - self.since), 0.0, 0.0)
        self.since = t
        pose = self.world.truth()
        self.app.set_pose(pose["x"], pose["y"], pose["heading"])


@long_test
def test_stop_arrives_before_the_stopping_distance_in_10_seeded_runs(server_factory: Any, sim_time: Any) -> None:
    """A frame every PERIOD s of simulated time (the monitor's -period): the stop must come
    while the rover, still driving on until the verdict is out (one frame later), is short of
    the stopping distance. In real time a loaded machine's slow cycles decided it instead."""
    srv = server_factory(["server.scene=office"])
    c = srv.client()
    world, app = srv.app.world, srv.app
    gnc = Gnc(app, world)
    sim = sim_time(app, PERIOD, gnc.on_frame)
    rock = max(world.rocks(), key=lambda r: r["height"])  # 0.20 m, above the 0.15 m step limit
    assert rock["height"] > 0.15
    results = []
    warned_first = 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        gap0, lateral, heading = rng.uniform(1.3, 1.9), rng.uniform(-0.12, 0.12), rng.uniform(-10, 10)
        place(world, rock, gap0, lateral, heading)
        t = world.truth()
        app.set_pose(t["x"], t["y"], t["heading"])
        r = c.request(f"hazard-start -period {PERIOD} -stop-distance {STOP} -warn-distance {WARN}")
        assert r.status == "OK", r
        sim.run()
        first, _ = sim.sync(c, "hazard")
        assert [e["level"] for e in first] == ["clear"]  # first cycle: nothing within the warn distance
        gnc.drive(sim.t)
        levels: list[str] = []
        for _ in range(round(gap0 / SPEED / PERIOD)):  # it would hit the rock before the last one
            sim.run()
            events, _ = sim.sync(c, "hazard")
            levels += [e["level"] for e in events]
            if "stop" in levels:
                break
        assert levels and levels[-1] == "stop", (seed, levels)
        ev = events[-1]
        gnc.move(sim.t)  # where the rover is when the verdict is out, and where the GNC stops it
        gnc.halt()
        gap = true_gap(world, rock)
        results.append((seed, gap, float(ev["distance"])))
        assert gap > STOP, f"seed {seed}: stop arrived {gap:.3f} m from the rock (stop distance {STOP})"
        assert 0.0 <= float(ev["distance"]) <= gap + 0.35, (seed, ev, gap)
        warned_first += levels[0] == "warning"  # it started beyond the warn distance
        if seed < 9:
            assert c.request("hazard-stop").fields["stopped"] == "true"
    assert warned_first == 10, warned_first  # a warning came first, every time
    # The rover turns away from the rock (and the GNC says so): the corridor clears. (To the
    # right: on its left stands the 0.14 m rock, whose flanks are steeper than the slope limit.)
    world.move_rover(0.0, 0.0, -90.0)
    assert min(true_gap(world, r, WIDTH + 0.4) for r in world.rocks()) > 2.5  # truly clear ahead
    t = world.truth()
    c.request(f"pose -x {t['x']:.4f} -y {t['y']:.4f} -heading {t['heading']:.3f}")
    # (Standing still short of the rock, the level may have eased from stop to warning first:
    # the stop also covered where the moving rover would have been by the next verdict.)
    sim.run(3)
    events, st = sim.sync(c, "hazard")
    assert events and events[-1]["level"] == "clear", events
    assert st["hazard_monitor"] == "running"
    # Cycle time without PTU motion, in simulated time: a frame's; the spec's bound (0.5 s on
    # the machine) is a speed, which tools/bench measures rather than a test.
    assert float(st["cycle_ms"]) == pytest.approx(1000 * PERIOD) == float(st["grab_ms"]), st
    r = c.request("hazard-stop")
    assert r.fields["stopped"] == "true" and int(r.fields["cycles"]) > 0
    print("gaps at stop:", [(s, round(g, 3), d) for s, g, d in results])


def test_monitor_yields_to_jobs_and_restores_its_pointing(server_factory: Any) -> None:
    srv = server_factory(["server.scene=office"])
    c = srv.client()
    world = srv.app.world
    r = c.request("hazard-start -period 0.05 -tilt -40")
    assert r.status == "OK" and r.fields["state"] == "running"
    next_event(c, "hazard")
    # A job is accepted as usual; the monitor pauses while it runs and says so. (The job lasts
    # until the break: a short one could end before a slow cycle of the monitor does.)
    job = c.start_job("sleep -seconds 60")
    ev = next_event(c, "hazard")
    assert ev["level"] == "paused" and ev["reason"] == "job" and ev["job"] == job
    operator = srv.client()
    assert operator.request("break").fields["interrupted"] == job
    assert c.until_final(job=job)[-1].fields["code"] == "E_INTERRUPTED"
    assert operator.request("continue").status == "OK"
    assert next_event(c, "hazard")["level"] == "clear"  # resumed: its level is sent again
    # A hardware job gets the PTU (it waits at most one monitor cycle), then the monitor points
    # back at its next cycle. (The move is instant at time_scale 0: the monitor may not even see
    # the job, so there is no EVENT to wait for; the wait is a safety net, not a speed bound.)
    final = c.request("move-ptu -pan 60 -tilt -10")
    assert final.status == "OK" and float(final.fields["pan"]) == pytest.approx(60, abs=0.1)
    assert wait_for(lambda: abs(world.truth()["pan"]) <= 0.1 and abs(world.truth()["tilt"] + 40) <= 0.1,
                    timeout=60), world.truth()
    st = c.request("status").fields
    assert st["hazard_monitor"] == "running" and float(st["cycle_ms"]) > 0
    # Only one holder of the PTU.
    r = c.request("track3d-start")
    assert r.status == "ERROR" and r.fields["code"] == "E_BUSY" and "hazard" in r.fields["message"]
    # break stops jobs, not monitors: it pauses in the break mode and runs again after continue.
    # (Requests from the operator's connection: c.request skips EVENT lines, and the pause event
    # may come before a status reply on c.)
    assert operator.request("break").status == "OK"
    assert operator.request("status").fields["hazard_monitor"] == "paused"
    ev = next_event(c, "hazard")  # once its thread has seen the break (it may be mid-cycle)
    while ev["level"] != "paused" or ev.get("reason") == "job":  # the move-ptu's pause and resume may come late
        ev = next_event(c, "hazard")
    assert ev["level"] == "paused" and ev["reason"] == "break", ev
    assert c.request("continue").status == "OK"
    assert next_event(c, "hazard")["level"] == "clear"  # resumed: its level is sent again
    assert c.request("status").fields["hazard_monitor"] == "running"
    # hazard-start while running restarts it with the new options.
    assert c.request("hazard-start -period 0.05 -tilt -45").fields["restarted"] == "true"
    r = c.request("hazard-stop")
    assert r.fields["stopped"] == "true"
    assert c.request("hazard-stop").fields["stopped"] == "false"
    assert "hazard_monitor" not in c.request("status").fields


def test_a_device_fault_ends_the_monitor_and_shutdown_stops_it(server_factory: Any) -> None:
    srv = server_factory(["server.scene=office"])
    c = srv.client()
    assert c.request("hazard-start -period 0.05").status == "OK"
    next_event(c, "hazard")
    assert c.request("sim fault -device tof -kind unplug").status == "OK"
    ev = next_event(c, "hazard")
    assert ev["level"] == "error" and ev["code"] == "E_DEVICE" and ev["device"] == "tof"
    assert c.request("status").fields["mode"] == "fault"
    assert "hazard" not in srv.app.monitors
    r = c.request("hazard-start")
    assert r.status == "ERROR" and r.fields["code"] == "E_STATE"
    # A second server: quit/shutdown with the monitor running ends its thread.
    srv2 = server_factory(["server.scene=office"])
    c2 = srv2.client()
    assert c2.request("hazard-start -period 0.05").status == "OK"
    monitor = srv2.app.monitors["hazard"]
    assert c2.request("quit").status == "OK"
    srv2.thread.join(20)
    assert not monitor.thread.is_alive()
    assert not srv2.thread.is_alive() and srv2.exit_code == 0


def test_hazard_start_arguments(server_factory: Any) -> None:
    srv = server_factory(["server.scene=office"])
    c = srv.client()
    r = c.request("hazard-start -stop-distance 2 -warn-distance 1")
    assert r.status == "ERROR" and r.fields["code"] == "E_ARG"
    r = c.request("hazard-start -tilt -80")
    assert r.status == "ERROR" and r.fields["code"] == "E_ARG" and "limits" in r.fields["message"]
    help_ = c.request("help hazard-start").fields
    assert help_["kind"] == "immediate" and "opt_lookahead" in help_
