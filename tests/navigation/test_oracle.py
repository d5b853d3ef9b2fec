"""The feasibility oracle (rvs_truth.oracle): the lattice search with the body's own vehicle check on
small synthetic 1 cm surfaces; the path it returns passes the truth check, a walled-in goal is
infeasible, and a mission's verdict is cached by everything it depends on."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from drivers.sim.rover import RoverBody
from prox_workflows.grid import GridGeometry
from rvs_truth import oracle as oracle_module
from rvs_truth.oracle import mission_key, mission_oracle, oracle
from rvs_truth.vehicle import vehicle_check

BODY = RoverBody()


def ground(width: float, height: float) -> tuple[np.ndarray, GridGeometry, np.ndarray, np.ndarray]:
    """A flat 1 cm surface over [0, width] x [0, height], and its cell centres' x, y."""
    g = GridGeometry.covering(0.0, 0.0, width, height, 0.01)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    return np.zeros(g.shape, np.float32), g, X, Y


def as_surface(h: np.ndarray, g: GridGeometry) -> tuple[np.ndarray, GridGeometry, GridGeometry]:
    return h, g, GridGeometry(0.05, g.xmin, g.ymax, g.width // 5, g.height // 5)


def test_a_path_round_a_rock_passes_the_truth_check() -> None:
    h, g, X, Y = ground(2.4, 2.0)
    # a 12 cm rock on the straight line: over the 8 cm belly and the 10 cm climb, so the body
    # must pass it with the rock outside its wheels
    h[np.hypot(X - 1.2, Y - 1.0) <= 0.06] = 0.12
    surface = as_surface(h, g)
    start, goal = (0.6, 1.0), (1.8, 1.0)
    straight = np.array([(*start, 0.0), (*goal, 0.0)])
    assert vehicle_check(straight, surface, BODY)[0]  # the straight line meets the rock
    out = oracle(surface, BODY, start, goal)
    assert out["feasible"] and out["reason"] == "found" and out["events"] == []
    path = np.array(out["path"])  # x, y, heading of every pose the rover drives
    assert path[0].tolist() == [*start, 0.0]  # facing the goal, as a mission starts
    assert np.hypot(*(path[-1, :2] - goal)) <= 0.05 / np.sqrt(2) + 1e-9
    assert 0.5 < out["efficiency"] < 1.0  # round the rock, not through it
    assert np.min(np.hypot(path[:, 0] - 1.2, path[:, 1] - 1.0)) > 0.25  # the rock passes outside the body's middle
    # the truth check, run here on the returned path, turns on the spot included, finds no event
    events, checked = vehicle_check(path, surface, BODY)
    assert events == [] and checked >= len(path)


def test_a_walled_in_goal_is_infeasible() -> None:
    h, g, X, Y = ground(2.5, 1.4)
    ring = np.maximum(np.abs(X - 1.6), np.abs(Y - 0.7))
    wall = (ring >= 0.42) & (ring <= 0.45)
    h[wall] = 0.3  # a 30 cm wall round the goal, 84 cm across inside: room for the body to turn
    out = oracle(as_surface(h, g), BODY, (0.5, 0.7), (1.6, 0.7))
    assert not out["feasible"] and out["reason"] == "exhausted" and out["efficiency"] == 0.0
    assert "path" not in out
    h[wall & (X < 1.3)] = 0.0  # the same wall with its near side taken away
    opened = oracle(as_surface(h, g), BODY, (0.5, 0.7), (1.6, 0.7))
    assert opened["feasible"] and opened["efficiency"] > 0.9


def test_a_verdict_is_cached_by_mission_body_and_code(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    h, g, X, Y = ground(2.0, 1.4)
    calls = []

    def fake_surface(world, scene):  # noqa: ANN001, ANN202 - the scene's surface, small and known
        calls.append(scene)
        return as_surface(h, g)

    monkeypatch.setattr("rvs_truth.surface.truth_surface", fake_surface)
    first = mission_oracle("quarry", 0, (0.6, 0.7), (1.4, 0.7), BODY, tmp_path)
    assert first["feasible"] and not first["cached"] and len(calls) == 1
    h[:] = 0.5 * (X > 0.6)  # a 50 cm cliff under the start: the mission would fail now, but the cache answers
    again = mission_oracle("quarry", 0, (0.6, 0.7), (1.4, 0.7), BODY, tmp_path)
    assert again["cached"] and again["feasible"] and len(calls) == 1
    lower = dataclasses.replace(BODY, climb=0.05)
    assert mission_key("quarry", 0, (0.6, 0.7), (1.4, 0.7), lower) != mission_key("quarry", 0, (0.6, 0.7),
                                                                                    (1.4, 0.7), BODY)
    other = mission_oracle("quarry", 0, (0.6, 0.7), (1.4, 0.7), lower, tmp_path)
    assert not other["cached"] and other["reason"] == "exhausted" and len(calls) == 2  # computed on the cliff
    monkeypatch.setattr(oracle_module, "code_version", lambda: "changed")
    assert mission_oracle("quarry", 0, (0.6, 0.7), (1.4, 0.7), BODY, tmp_path)["cached"] is False


def test_the_cache_key_follows_the_vehicle_checks_compiled_kernel(monkeypatch: pytest.MonkeyPatch) -> None:
    """The check's per-pose work is in its kernel module: a change there changes the verdicts."""
    kernel = Path(oracle_module.vehicle.__file__).with_name("_vehicle_kernel.py")
    before = oracle_module.code_version()
    read = Path.read_bytes
    monkeypatch.setattr(Path, "read_bytes", lambda self: read(self) + (b"# edited" if self == kernel else b""))
    assert oracle_module.code_version() != before


def test_the_bench_counts_the_oracles_feasible_missions_beside_the_window_steps() -> None:
    from tools.bench.navigate import summarise

    def row(feasible: bool, window: bool, reached: bool) -> dict:
        return {"scene": "hirise", "mode": "see", "start": (0.0, 0.0), "distance": 16.0, "true_miss": 15.0,
                "reached": reached, "feasible": feasible, "perfect_efficiency": 0.95 if feasible else 0.0,
                "window_feasible": window, "window_efficiency": 0.7 if window else 0.0, "efficiency": 0.5 * reached,
                "events": [], "crossed_cells": 0, "today_plan": {"events": []}, "sim_s": 100.0, "wall_s": 10.0}

    s = summarise([row(True, False, True), row(True, False, False), row(False, False, False)])[0]
    assert (s["feasible"], s["window_feasible"], s["reached_of_feasible"]) == (2, 0, 1)
    assert s["perfect_efficiency_feasible"] == pytest.approx(0.95)


def test_a_path_is_timed_as_the_simulated_rover_drives_it() -> None:
    """The oracle's path in the mission's own measure (time at the rover's speed and turn rate):
    a straight at top speed, a turn on the spot at the turn rate, a tight arc no faster than the
    turn rate turns it, a wide one at top speed."""
    from tools.bench.navigate import drive_time

    straight = np.array([(0.0, 0.0, 0.0), (0.5, 0.0, 0.0), (1.0, 0.0, 0.0)])
    assert drive_time(straight, 0.1, 15.0) == pytest.approx(10.0)
    spot = np.array([(0.0, 0.0, 170.0), (0.0, 0.0, -100.0)])  # 90 deg the short way, across +-180
    assert drive_time(spot, 0.1, 15.0) == pytest.approx(6.0)
    t = np.radians(np.linspace(0.0, 90.0, 10))  # a quarter circle in nine 10-degree steps

    def arc(radius: float) -> np.ndarray:
        return np.column_stack([radius * np.sin(t), radius * (1 - np.cos(t)), np.degrees(t)])

    assert drive_time(arc(0.2), 0.1, 15.0) == pytest.approx(6.0)  # 90 deg at 15 deg/s: the turn rate rules
    chords = 9 * 2 * 2.0 * np.sin(np.radians(5.0))  # 3.1 m of chords: top speed rules
    assert drive_time(arc(2.0), 0.1, 15.0) == pytest.approx(chords / 0.1)

def test_the_bench_sets_a_missions_efficiencies_beside_the_oracles_in_both_measures() -> None:
    from tools.bench.navigate import summarise

    base = {"scene": "marsyard", "mode": "see", "start": (0.0, 0.0), "distance": 16.0, "true_miss": 0.1,
            "reached": True, "feasible": True, "perfect_efficiency": 0.95, "window_feasible": True,
            "window_efficiency": 0.7, "events": [], "crossed_cells": 0, "today_plan": {"events": []},
            "sim_s": 400.0, "wall_s": 10.0}
    rows = [{**base, "efficiency": 0.4, "path_efficiency": 0.8, "oracle_time_efficiency": 0.7},
            {**base, "efficiency": 0.2, "path_efficiency": 0.6, "oracle_time_efficiency": 0.9},
            {**base, "efficiency": 0.3}]  # a row from before the two were measured
    rows[0]["time_split"] = {"drive": 300.0, "turn on the spot": 60.0, "ptu moves": 40.0}
    rows[1]["time_split"] = {"drive": 200.0, "ptu moves": 200.0}
    s = summarise(rows)[0]
    # the share of the simulated time of the runs that record it, whatever else each row holds
    assert s["time_split"] == pytest.approx({"drive": 0.625, "ptu moves": 0.3, "turn on the spot": 0.075})
    assert s["efficiency_reached"] == pytest.approx(0.3)
    assert (s["path_efficiency_reached"], s["oracle_time_efficiency_same"]) == (pytest.approx(0.7), pytest.approx(0.8))
