"""The chooser's loop of looks before a drive (rvs_server/navigation/sections.py ``Chooser.drive_on``)
on scripted choices: what it asks of the mast, with which settings it chooses again, and where a
section back to where the rover stood leaves a dead end."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np

from drivers.sim.rover import RoverBody
from prox_workflows.algorithms.candidates import CandidateParams, Choice
from prox_workflows.algorithms.retreat import RetreatBudget, RetreatParams
from rvs_server.navigation.sections import Chooser


class _Driver:
    """The seeing driver's part the loop uses: a look from a place is taken once (as
    ``SeeingDriver.look_at`` does, by ``looks.looked_from_here``)."""

    def __init__(self) -> None:
        self.looks: list[tuple[float, float, str]] = []
        self.rounds = 0
        self.looked = False
        self.set_down_pending = False
        self.p = SimpleNamespace(chooser=CandidateParams(), chance=None, retreat=RetreatParams(), keep_moved=2.0)
        self.body = RoverBody()
        self.at = (0.0, 0.0, 0.0)
        self.bounds = SimpleNamespace(frames=3)

    def pose(self) -> tuple[float, float, float]:
        return self.at

    def look_at(self, x: float, y: float, pose: tuple[float, float, float], what: str = "unseen ground") -> bool:
        if self.looked:
            return False
        self.looked = True
        self.looks.append((x, y, what))
        return True

    def look_round(self) -> None:
        self.rounds += 1


def _chooser(script: list[Choice]) -> tuple[Chooser, _Driver, list[tuple[Any, bool]], list[Choice]]:
    d = _Driver()
    c = Chooser.__new__(Chooser)
    c.d, c.params, c.rounds, c.started = d, d.p.chooser, [(0.0, 0.0)], True
    c.best, c.since_best, c.stood, c.dead_ends, c.retreat = math.inf, 0, [], [], d.p.retreat
    c.budget = RetreatBudget(d.p.retreat)
    said: list[str] = []
    c.s = SimpleNamespace(job=SimpleNamespace(check=lambda: None), stats=SimpleNamespace(replans=0), kept=False, moved=None,
                          sets_down=True, cover=[(0.0, 0.0), (5.0, 0.0)],
                          mission=SimpleNamespace(goal=(5.0, 0.0), progress=lambda leg, done, total, message,
                                                  phase="": said.append(message)))
    c.said = said  # type: ignore[attr-defined]
    calls: list[tuple[Any, bool]] = []
    driven: list[Choice] = []

    def choose(pose: Any, look_cost: Any, ray_looks: bool = True) -> tuple[Choice, float]:
        calls.append((look_cost, ray_looks))
        return script[min(len(calls), len(script)) - 1], 5.0

    c._choose = choose  # type: ignore[method-assign]
    c._look_round = lambda pose: (c.rounds.append(pose[:2]), d.look_round())  # type: ignore[method-assign]

    def drive(leg: int, choice: Choice, what: str = "") -> None:
        driven.append(choice)
        d.at = tuple(choice.poses[-1])

    c.drive = drive  # type: ignore[method-assign]
    return c, d, calls, driven


def _look(for_: str, at: tuple[float, float]) -> Choice:
    return Choice("look", "look there", np.zeros((0, 3)), np.zeros((0, 3)), look_at=at, look_for=for_)


def _drive(to: tuple[float, float] = (0.0, 0.0)) -> Choice:
    poses = np.array([[0.0, 0.0, 0.0], [to[0], to[1], 0.0]])
    return Choice("drive", "passes", poses, poses, rank=7)


def test_ground_only_a_ray_bounds_is_looked_at_once_from_a_place_then_judged_as_it_is() -> None:
    """The first ray look takes a frame toward the ground; asked again from the same place, the
    loop chooses with the ray looks off (no look round: ground a frame from here would show, the
    frame taken showed), and drives what then passes."""
    c, d, calls, driven = _chooser([_look("ray", (1.8, 0.2)), _look("ray", (2.0, -0.4)), _drive()])
    assert c.drive_on(0)
    assert d.looks == [(1.8, 0.2, "ground only a ray bounds")]
    assert d.rounds == 0
    assert calls == [(None, True), (None, True), (None, False)]
    assert [ch.status for ch in driven] == ["drive"]


def test_unseen_ground_still_gets_its_look_round_after_a_ray_look() -> None:
    """A look for unseen ground that one frame from here does not settle goes on to the look
    round, as before: the ray looks do not take its place."""
    c, d, calls, driven = _chooser([_look("ray", (1.8, 0.2)), _look("unseen", (0.9, 0.0)), _drive()])
    c.rounds = [(5.0, 5.0)]  # looked round elsewhere, not here
    assert c.drive_on(0)
    assert d.looks == [(1.8, 0.2, "ground only a ray bounds")]
    assert d.rounds == 1
    assert calls == [(None, True), (None, True), (None, True)]
    assert len(driven) == 1


def test_a_section_back_to_where_the_rover_stood_no_closer_leaves_a_dead_end_where_it_stands() -> None:
    """From A the rover drives to B; from B, no closer by the cost to go, the chosen section leads
    back to A: B is priced as a dead end (the ground A's choice reads next), the section is driven
    as the way out, and no reverse is made. A section on to new ground, or a turn on the spot,
    leaves none."""
    c, d, calls, driven = _chooser([_drive((0.9, 0.0)), _drive((1.5, 0.6)), _drive((1.5, 0.6)), _drive((0.05, 0.1))])
    assert c.drive_on(0) and d.at[:2] == (0.9, 0.0)
    assert c.drive_on(0) and d.at[:2] == (1.5, 0.6)  # on to new ground
    assert c.drive_on(0) and d.at[:2] == (1.5, 0.6)  # a turn on the spot where it stands
    assert c.dead_ends == []
    assert c.drive_on(0) and d.at[:2] == (0.05, 0.1)  # back to A
    assert [(e.x, e.y, e.radius) for e in c.dead_ends] == [(1.5, 0.6, RetreatParams().radius)]
    assert c.said == ["dead end at (1.50, 0.60): the way on leads back to (0.00, 0.00), no closer"]
    assert len(driven) == 4 and c.since_best == 3


def test_a_safe_stop_where_the_rover_was_set_down_says_what_the_operator_can_do() -> None:
    """Stopped where it was set down (fresh, or set down again on a kept map after the GNC moved
    it), the stop says that the GNC may back it out and navigate take this map; stopped elsewhere,
    on the kept map where the rover still stands, or with keep_moved 0, it says nothing more."""
    c, d, _, _ = _chooser([])
    hint = c.set_down_hint((0.1, 0.0, 0.0))
    assert "has not left where it was set down" in hint and "navigate.see_keep_moved, 2 m" in hint
    assert c.set_down_hint((0.5, 0.0, 0.0)) == ""  # past the body's reach: it left
    c.s.kept, c.s.moved = True, 0.6  # set down again on the last navigate's map, after the GNC's drive
    assert c.set_down_hint((0.0, 0.0, 0.0)) == hint
    c.s.moved, c.s.sets_down = None, False  # on that map where the rover still stands: no set-down
    assert c.set_down_hint((0.0, 0.0, 0.0)) == ""
    c.s.kept, c.s.sets_down = False, True
    d.p.keep_moved = 0.0
    assert c.set_down_hint((0.0, 0.0, 0.0)) == ""
