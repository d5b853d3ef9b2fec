"""Edges of the server through real sockets and real processes: the monitors' timing figures,
the web console's port, shutdown on a signal, and protocol corner cases (overlong lines,
comments, control characters, ranges the device gives)."""

from __future__ import annotations

from typing import Any

import pytest


def test_monitor_mean_and_longest_cycle_cover_the_same_cycles(server_factory: Any, sim_time: Any,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """In simulated time every cycle lasts one frame, except the first, made to last ten (as
    one that fills the caches does): the mean may not count it where the maximum does not."""
    srv = server_factory(["server.scene=office"])
    c = srv.client()
    frame = 0.1
    sim = sim_time(srv.app, frame)
    tof = srv.app.devices.get("tof")
    gated = tof.grab_xyz
    frames = []

    def first_frame_slow(*args: Any, **kwargs: Any) -> Any:
        out = gated(*args, **kwargs)
        if not frames:
            sim.clock.start += 9 * frame  # the clock is counted in frames: this one took ten
        frames.append(1)
        return out

    monkeypatch.setattr(tof, "grab_xyz", first_frame_slow)
    assert c.request(f"hazard-start -period {frame}").status == "OK"
    sim.run(5)
    _, st = sim.sync(c, "hazard")
    assert int(st["hazard_cycles"]) == 5
    assert float(st["cycle_ms"]) <= float(st["cycle_ms_max"]), st
    assert float(st["cycle_ms"]) == pytest.approx(1000 * frame) == float(st["cycle_ms_max"]), st
    assert st["timed_cycles"] == "4", st  # the first is not timed
    r = c.request("hazard-stop")
    assert float(r.fields["cycle_ms"]) <= float(r.fields["cycle_ms_max"]) and r.fields["timed_cycles"] == "4", r
