"""The chooser's loop of looks before a drive (rvs_server/navigation/sections.py ``Chooser.drive_on``)
on scripted choices: what it asks of the mast, and with which settings it chooses again."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np

from prox_workflows.algorithms.candidates import CandidateParams, Choice
from rvs_server.navigation.sections import Chooser


class _Driver:
    """The seeing driver's part the loop uses: a look from a place is taken once (as
    ``SeeingDriver.look_at`` does, by ``looks.looked_from_here``)."""

    def __init__(self) -> None:
        self.looks: list[tuple[float, float, str]] = []
        self.rounds = 0
        self.looked = False
        self.set_down_pending = False
        self.p = SimpleNamespace(chooser=CandidateParams(), chance=None, retreat=SimpleNamespace())

    def pose(self) -> tuple[float, float, float]:
        return (0.0, 0.0, 0.0)

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
    c.best, c.since_best = math.inf, 0
    c.s = SimpleNamespace(job=SimpleNamespace(check=lambda: None), stats=SimpleNamespace(replans=0))
    calls: list[tuple[Any, bool]] = []
    driven: list[Choice] = []

    def choose(pose: Any, look_cost: Any, ray_looks: bool = True) -> tuple[Choice, float]:
        calls.append((look_cost, ray_looks))
        return script[min(len(calls), len(script)) - 1], 5.0

    c._choose = choose  # type: ignore[method-assign]
    c._look_round = lambda pose: (c.rounds.append(pose[:2]), d.look_round())  # type: ignore[method-assign]
    c.drive = lambda leg, choice, what="": driven.append(choice)  # type: ignore[method-assign]
    return c, d, calls, driven


def _look(for_: str, at: tuple[float, float]) -> Choice:
    return Choice("look", "look there", np.zeros((0, 3)), np.zeros((0, 3)), look_at=at, look_for=for_)


def _drive() -> Choice:
    return Choice("drive", "passes", np.zeros((2, 3)), np.zeros((2, 3)), rank=7)


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
