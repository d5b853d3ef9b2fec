"""The see loop's start with the body's hazard cameras on (drivers.hazcam.cameras, both pairs on the
simulated rover): a turn on the spot shows the pairs the ground between the body and the mast's blind disc, which no tilt of the
mast shows, and the set-down's prior is left only where no camera saw. Through the real server;
the bounds map is read where the chooser makes its first choice."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from support.marks import long_test

import rvs_server.navigation.sections as sections
from drivers.base import DeviceError
from rvs_server.devices import DeviceRegistry, stereo_points
from rvs_server.main import build_config, make_world
from rvs_server.navigation.see import BLIND_EDGE, map_pairs
from rvs_server.protocol import ProtocolError

STOP = "the first choice"


def _at_first_choice(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """What the bounds map holds round the rover when the chooser first chooses: the ring (the
    mast's blind disc, past the body's own rectangle grown by 5 cm), its cells that a frame
    bounded, the disc's cells under that rectangle, and the disc's cells that only the set-down's
    prior (and the wheels' contacts) gave bounds."""
    seen: dict[str, Any] = {}
    choose = sections.Chooser._choose

    def first(self: sections.Chooser, pose: tuple[float, float, float], look_cost: float | None,
              ray_looks: bool = True) -> Any:
        if not seen:
            d = self.d
            fx, fy, radius = d.blind_disc()
            g = d.bounds.geometry
            xs, ys = g.centers()
            X, Y = np.meshgrid(xs, ys)
            h = math.radians(pose[2])
            along = (X - pose[0]) * math.cos(h) + (Y - pose[1]) * math.sin(h)
            across = -(X - pose[0]) * math.sin(h) + (Y - pose[1]) * math.cos(h)
            body = (np.abs(along) <= d.body.length / 2 + 0.05) & (np.abs(across) <= d.body.width / 2 + 0.05)
            disc = np.hypot(X - fx, Y - fy) <= radius + BLIND_EDGE
            framed = d.bounds.stamp > 0
            seen.update(pose=pose, ring=int((disc & ~body).sum()), ring_framed=int((disc & ~body & framed).sum()),
                        body=int((disc & body).sum()), prior=int((disc & np.isfinite(d.bounds.mean) & ~framed).sum()))
            raise ProtocolError("E_DATA", STOP)  # the start is what is measured: no drive after it
        return choose(self, pose, look_cost, ray_looks)

    monkeypatch.setattr(sections.Chooser, "_choose", first)
    return seen


def _start(server_factory: Any, monkeypatch: pytest.MonkeyPatch, *settings: str) -> dict[str, Any]:
    seen = _at_first_choice(monkeypatch)
    # one ToF frame a position of the look round: its averaging is not what is measured here
    srv = server_factory(["server.scene=quarry", *settings, "navigate.see_look_frames=1",
                          "drivers.ptu.timeout=30"])  # the PTU emulator answers late on a loaded machine
    srv.app.world.set_target_visible(False)
    c = srv.client()
    job = c.start_job("navigate -start 0,0,0 -goal 2.0,0 -auto -loop see -name start")
    final = c.until_final(job=job, timeout=900)[-1]
    assert final.status == "ERROR" and final.fields["message"].startswith(STOP), final.fields
    return seen


@long_test  # a whole start with both pairs (15 s of CPU, the default run's heaviest test): CI's long suite
@pytest.mark.timeout(900)  # the start renders some 40 ToF and 20 hazcam frames: minutes on a loaded machine
def test_the_simulated_rover_s_start_turn_shows_its_pairs_the_ring_round_the_body(server_factory, monkeypatch) -> None:
    """The simulated rover carries both pairs (config/drivers.yaml), looking ahead and behind, 90
    deg across each: two turns of 60 deg on the spot at the start put the ground all round before
    them. At the first choice nearly the whole ring between the body and the mast's blind disc
    has a frame's bounds, and the set-down's prior is left on a small part of the disc (under the
    body and a narrow band round it)."""
    seen = _start(server_factory, monkeypatch)
    assert abs((seen["pose"][2] - 120.0 + 180.0) % 360.0 - 180.0) < 3.0, seen  # facing where the turn left it
    assert seen["ring_framed"] >= 0.85 * seen["ring"], seen
    assert seen["prior"] <= seen["body"] + 0.1 * seen["ring"], seen


@long_test  # a whole start, 15-30 s: the default run's 6 minutes; CI's long suite runs it
@pytest.mark.timeout(900)
def test_with_the_hazcams_off_the_start_is_unchanged(server_factory, monkeypatch) -> None:
    """Without the body's cameras the start does not turn, and the mast's blind disc is the
    set-down's prior: only its edge, which the mast's rays graze, has a frame's bounds."""
    seen = _start(server_factory, monkeypatch, "drivers.hazcam.cameras=off")
    assert abs(seen["pose"][2]) < 3.0, seen
    assert seen["ring_framed"] <= 0.3 * seen["ring"], seen
    assert seen["prior"] >= 0.6 * seen["ring"], seen


def test_simulated_pairs_beside_a_real_tof_are_refused_and_beside_the_simulated_one_feed_the_map() -> None:
    """A simulated pair renders the simulator's world: beside a real ToF (here the SR4000's
    library, absent, so the ToF is not even open) it would lay that world into the rover's map."""
    for tof, pairs in (("mesasr", None), ("sim", ["front", "rear"])):
        store = build_config(None, [f"drivers.tof.backend={tof}"])
        devices = DeviceRegistry(store.get("drivers"), make_world(store), matcher=stereo_points)
        devices.open("hazcam")
        app = SimpleNamespace(devices=devices)
        if pairs is None:
            with pytest.raises(DeviceError, match="ToF is mesasr: a simulated pair must not feed a real rover's map; "
                                                  "set drivers.hazcam.cameras off"):
                map_pairs(app)
        else:
            assert map_pairs(app) == pairs
        devices.close()
