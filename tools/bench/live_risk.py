"""The live check's stated risk, measured in the loop: every pose the see loop's vehicle checks
judge during a mission (the chooser's candidates, and the section being driven re-judged each
cycle), checked again after the mission on the simulator's true 1 cm surface. A pass on a pose the
truth finds over a limit is a false safe.

This is the stated risk (the false-safe rate per judged pose) taken on the judgements the loop really
makes, on maps fused from every look and cycle as they were when it judged. The risk bench
(``tools.bench.chance --risk``) takes it on one look's map, on poses 1.6-4 m out. The section
being driven (``drive``) holds each pose's last judgements before the wheels reach it, the ones
the wheels depend on.

:class:`Recorder` hooks the checks the loop builds (:mod:`rvs_server.navigation.sections`) while
installed; :func:`live_risk` sums a recording against the truth. ``tools.bench.gate_trace`` and
``tools.bench.navigate --live-risk`` use them.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

import rvs_server.navigation.sections as sections
from prox_workflows.algorithms import vehicle
from prox_workflows.algorithms.candidates import SAFE, UNKNOWN
from rvs_truth.stats import clopper_pearson_upper

Truth = Callable[[np.ndarray], vehicle.PoseChecks]  # the truth's check of (N, 3) poses wherever they are
PARTS = ("choose", "drive", "all")


class Recorder:
    """Every check's poses and verdicts while :meth:`installed`: which check (``chance``, the
    chance constraint the loop drives on; ``bounds``, the worst case and the track back's
    best-estimate check), where (``choose`` or ``drive``) and the choice it belongs to (set by
    whoever counts the choices; -1 otherwise)."""

    def __init__(self) -> None:
        self.judged: list[tuple[np.ndarray, np.ndarray, str, str, int]] = []
        self.where = "choose"
        self.choice = -1

    def _traced(self, make: Any, kind: str) -> Any:
        def build(*a: Any, **k: Any) -> Any:
            check = make(*a, **k)

            def run(poses: np.ndarray) -> np.ndarray:
                codes = np.asarray(check(poses))
                self.judged.append((np.atleast_2d(poses).astype(np.float32), codes.astype(np.int8), kind,
                                    self.where, self.choice))
                return codes

            return run

        return build

    @contextlib.contextmanager
    def installed(self) -> Iterator[Recorder]:
        recheck = sections.SectionPilot._recheck
        kept = sections.posterior_check, sections.bounds_check

        def driving(pilot: Any, pose: Any) -> Any:
            self.where = "drive"
            try:
                return recheck(pilot, pose)
            finally:
                self.where = "choose"

        sections.posterior_check = self._traced(sections.posterior_check, "chance")
        sections.bounds_check = self._traced(sections.bounds_check, "bounds")
        sections.SectionPilot._recheck = driving
        try:
            yield self
        finally:
            sections.posterior_check, sections.bounds_check = kept
            sections.SectionPilot._recheck = recheck

    def refusals(self) -> Iterator[tuple[np.ndarray, int, str, int]]:
        """Each refused pose (a limit exceeded), in the order judged: pose, verdict, where, choice."""
        for poses, codes, _, where, choice in self.judged:
            for p, code in zip(poses[codes > 0], codes[codes > 0], strict=True):
                yield p, int(code), where, choice


def live_risk(judged: list[tuple[np.ndarray, np.ndarray, str, str, int]], truth: Truth, kind: str = "chance",
              chunk: int = 200_000) -> dict[str, dict[str, Any]]:
    """Per part (``choose``, ``drive``, ``all``) of ``kind``'s judgements with a verdict (unknown
    left out): judged, passed, truly unsafe, false safes and their one-sided 95 % bound, per
    judgement and per distinct pose (1 cm, 1 deg). The loop judges the same pose again cycle
    after cycle, so the count per distinct pose stands beside it: the bound assumes the judgements
    independent, which repeats are not. Each distinct pose is judged by the truth once."""
    out: dict[str, dict[str, Any]] = {}
    for part in PARTS:
        calls = [(p, c, i) for p, c, k, w, i in judged if k == kind and part in ("all", w)]
        if not calls:
            continue
        poses = np.concatenate([p for p, _, _ in calls])
        codes = np.concatenate([c for _, c, _ in calls])
        choice = np.concatenate([np.full(len(p), i) for p, _, i in calls])
        keep = codes != UNKNOWN
        poses, codes, choice = poses[keep], codes[keep], choice[keep]
        if not len(codes):
            continue
        key = np.column_stack([np.round(poses[:, :2] * 100), np.round(poses[:, 2]) % 360]).astype(np.int64)
        _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
        inverse = inverse.ravel()
        unsafe_distinct, off = np.zeros(len(first), bool), np.zeros(len(first), bool)
        for a in range(0, len(first), chunk):
            on_truth = truth(poses[first[a:a + chunk]].astype(float))
            unsafe_distinct[a:a + chunk], off[a:a + chunk] = on_truth.unsafe, on_truth.unknown
        # a pose the truth cannot judge (its body past the world's terrain: never unsafe there) is
        # left out of the counts, as the check's own unknowns are
        known = ~off[inverse]
        unsafe = unsafe_distinct[inverse]
        passed = codes == SAFE
        false = passed & unsafe
        false_distinct = np.unique(inverse[false])
        n, distinct = int(known.sum()), int((~off).sum())
        if not n:
            continue
        out[part] = {"judged": n, "distinct": distinct, "passed": int((passed & known).sum()),
                     "truly_unsafe": int(unsafe.sum()), "false_safes": int(false.sum()),
                     "false_safes_distinct": int(len(false_distinct)),
                     "bound": clopper_pearson_upper(int(false.sum()), n),
                     "bound_distinct": clopper_pearson_upper(len(false_distinct), distinct),
                     "misses": [{"pose": [round(float(v), 3) for v in poses[first[d]]],
                                 "choice": int(choice[first[d]])} for d in false_distinct[:50]]}
    return out


def summed(rows: list[dict[str, dict[str, Any]]]) -> dict[str, dict[str, Any]]:
    """Missions' :func:`live_risk` summed per part, the bounds taken again on the sums."""
    out: dict[str, dict[str, Any]] = {}
    for part in PARTS:
        rs = [r[part] for r in rows if part in r]
        if not rs:
            continue
        s = {k: sum(r[k] for r in rs) for k in ("judged", "distinct", "passed", "truly_unsafe", "false_safes",
                                                 "false_safes_distinct")}
        s["bound"] = clopper_pearson_upper(s["false_safes"], s["judged"])
        s["bound_distinct"] = clopper_pearson_upper(s["false_safes_distinct"], s["distinct"])
        out[part] = s
    return out


def lines(live: dict[str, dict[str, Any]]) -> list[str]:
    """A line per part, as the benches print it."""
    return [f"live check, {part}: {r['judged']} judged poses ({r['distinct']} distinct), {r['passed']} passed, "
            f"{r['false_safes']} false safes ({r['false_safes_distinct']} distinct), 95 % bound "
            f"{r['bound']:.2g} per judged pose ({r['bound_distinct']:.2g} per distinct pose)" for part, r in live.items()]
