"""Backing out of a dead end: the reverse sections the chooser may drive when nothing forward
passes, and the cost a dead end leaves on the cost to go.

Why
    The arc tree (:mod:`.candidates`) drives forward only. In a pocket the body cannot turn in
    (hirise's tight rocks, or a rock dropped just ahead), every turn on the spot and every arc
    fails on the body's limits, and a forward-only chooser stands there for good. A rover backs
    out: along the track it has just driven, whose ground its wheels and body were on, or on a
    short reverse arc its check passes. Where it came from it had other candidates ranked; the
    pocket is left with a price on it (:class:`DeadEnd`) so that the next choice does not drive
    back into it at once.

What this module holds (plain functions; the loop that drives them is
``rvs_server.navigation.sections``)
    - :class:`RetreatParams`: how many retreats the rover may make before it comes closer to the
      goal, the reverse arcs, and the dead end's disc and cost; :class:`RetreatBudget` keeps the
      count.
    - :func:`reverse_options`: the reverse sections from a pose: the track back (the rover's
      last arc driven backwards to where it began) and ``arcs`` reverse arcs.
    - :func:`choose_reverse`: the track back where it passes, else the cheapest reverse arc by the
      cost to go at its end that the check passes. A reverse arc passes only where every pose is judged safe (unseen ground under the
      body's rear fails it, as it fails a forward section); the track back also passes where a
      pose's ground is unknown to its check, since the body stood on every pose of it, but not
      where frames now show a limit exceeded (a rock dropped on the track is seen there).
    - :class:`DeadEnd`, :func:`add_dead_ends` and :func:`dead_end_penalty`: a dead end is a cost
      per metre on the coarse grid's cells within its disc, and on every candidate path over it
      (the cost to go is read at a path's end, past the disc it crossed): a cost, never a wall,
      since the map that refused may be wrong. It
      expires when frames taken from outside its neighbourhood cover its ground
      (:meth:`DeadEnd.expired`): the frames the rover takes from inside the pocket are what
      refused, and a look from elsewhere is new evidence.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from rvs_params import Settings, param

from ..grid import GridGeometry
from .arcs import arc_poses, default_curvatures
from .candidates import SAFE, Check, Choice, CostToGo, verdict_name
from .vehicle import VehicleBody, densify

__all__ = ["RetreatParams", "RetreatBudget", "ReverseOption", "DeadEnd", "reverse_options", "choose_reverse",
           "add_dead_ends", "dead_end_penalty"]


@dataclass
class RetreatParams(Settings):
    """Backing out of dead ends, and the price a dead end leaves on the cost to go."""

    retreats: int = param(12, "dead ends the rover may back out of (a reverse section each, then it chooses "
                              "again) before it stands `regain` m closer to the goal than it stood when the count "
                              "began; at the next one, or where no reverse section passes, the mission is a safe "
                              "stop with the reason (0: no backing out). Each reverse section is checked as a forward "
                              "one; through dense rock one way on took 9 (docs/NAVIGATE_BENCH.md)", min=0, max=100)
    regain: float = param(2.0, "coming this much closer to the goal (straight) than the rover stood when the count "
                               "of retreats began, or half the way there where that is less, starts it again: a "
                               "long traverse through rock meets more pockets than a short one, and progress "
                               "bounds how often the count restarts (0: the count is the mission's)", unit="m",
                          min=0.0, max=1000.0)
    length: float = param(0.6, "length of each reverse arc, driven backwards", unit="m", min=0.1, max=3.0)
    arcs: int = param(5, "curvatures of the reverse arcs, evenly spaced from the chooser's tightest left to its "
                         "tightest right", min=1, max=31)
    radius: float = param(0.6, "a dead end prices the ground within this distance of where the rover stood",
                          unit="m", min=0.0, max=5.0)
    cost: float = param(4.0, "a dead end's price per metre of the cost to go over its disc (added to the ground's "
                             "own; not a wall)", unit="m", min=0.0, max=1000.0)
    clear: float = param(1.0, "a dead end expires once frames taken farther than this beyond its disc cover its "
                              "ground (frames from inside the pocket are what refused it)", unit="m",
                         min=0.0, max=10.0)


@dataclass
class RetreatBudget:
    """The retreats the rover may still make: ``params.retreats`` counted from where it stood when
    the count began, begun again each time it stands ``params.regain`` m closer to the goal than
    there (half the way there, nearer than twice that: the last metres have pockets too).

    Why: a budget for the whole mission ends a long traverse through rock at its fifth pocket
    however far it had got, and each retreat costs time, not safety (a reverse section is checked
    as any other). The straight distance to the goal only shrinks so far, so the count begins
    again at most distance / regain times: the mission stays bounded."""

    params: RetreatParams
    made: int = 0  # retreats since the count began
    count_from: float = math.inf  # the rover's straight distance to the goal when it began

    @property
    def regain(self) -> float:
        """How much closer the rover must stand for the count to begin again."""
        return min(self.params.regain, self.count_from / 2.0)

    def stand(self, to_goal: float) -> None:
        """The rover stands ``to_goal`` m from the goal (straight), choosing its next section."""
        if self.count_from == math.inf or (self.regain > 0.0 and to_goal <= self.count_from - self.regain):
            self.count_from, self.made = to_goal, 0

    @property
    def spent(self) -> bool:
        return self.made >= self.params.retreats

    def __str__(self) -> str:
        """The count for a safe stop's reason, with where it began."""
        made = f"{self.made} of {self.params.retreats} retreats made"
        if self.params.retreats == 0:
            return made
        if self.params.regain <= 0.0:
            return f"{made} in the mission"
        return f"{made} since the rover stood {self.count_from:.2f} m from the goal, none {self.regain:.2f} m closer"


@dataclass(frozen=True)
class ReverseOption:
    """One reverse section: ``poses`` from the rover's pose backwards (heading the body's), driven
    at ``curvature`` (1/m, per metre of forward travel) for ``length`` metres backwards;
    ``track``: the rover's own last arc, whose ground it drove."""

    poses: np.ndarray
    curvature: float
    length: float
    track: bool


def reverse_options(pose: Sequence[float], track_back: tuple[float, float] | None, params: RetreatParams,
                    max_curvature: float, step: float) -> list[ReverseOption]:
    """The reverse sections from ``pose`` (x, y, heading deg): the track back first where there
    is one (``track_back``: the curvature and the metres of the last arc driven; reversed, it ends
    where that arc began), then ``params.arcs`` arcs of ``params.length`` backwards, poses at most
    ``step`` apart."""
    out: list[ReverseOption] = []
    if track_back is not None and track_back[1] > 1e-3:
        k, metres = track_back
        out.append(ReverseOption(_back(pose, k, metres, step), float(k), float(metres), True))
    ks = default_curvatures(1.0 / max_curvature, params.arcs) if max_curvature > 0 and params.arcs > 1 \
        else np.zeros(1)
    for k in ks:
        out.append(ReverseOption(_back(pose, float(k), params.length, step), float(k), params.length, False))
    return out


def _back(pose: Sequence[float], k: float, metres: float, step: float) -> np.ndarray:
    poses = arc_poses(pose, k, -metres, step)
    poses[:, 2] = (poses[:, 2] + 180.0) % 360.0 - 180.0
    return poses


def choose_reverse(pose: Sequence[float], options: list[ReverseOption], check: Check, ctg: CostToGo,
                   track_check: Check | None = None, body: VehicleBody | None = None, verify: float = 0.0
                   ) -> Choice:
    """The track back where it passes, else the cheapest reverse arc that passes by the cost to go
    at its end, as a ``drive`` :class:`~.candidates.Choice` with ``backward`` set; or ``blocked``
    with each option's failure. The track back comes first whatever an arc's end is worth: its
    ground is the one ground the body itself proved, where an arc is judged on the map that just
    failed to show a way on (in the start's blind disc, on the set-down's guess at the ground).
    The reverse arcs are judged with ``check`` (in one call); the track back with ``track_check``
    where given (the see loop's: the best estimate of the cells frames bounded,
    ``sections.track_check``): the body stood on every pose of it, so what can refuse it is ground
    that changed since, which only a frame shows (a rock that fell there), not the draws of a map
    that never bounded a wheel's patch as closely as the wheel itself did, nor a prior's guess at
    ground no frame saw. An unknown verdict does not refuse the track back. With ``verify`` above
    0, the option about to be chosen is judged again between its poses, that far apart at
    ``body``'s farthest point (``CandidateParams.verify_step``), and passed over if that fails."""
    if not options:
        return Choice("blocked", "no reverse section to judge", np.zeros((0, 3)), np.zeros((0, 3)))
    ends = np.array([o.poses[-1, :2] for o in options])
    cost = ctg.at(ends[:, 0], ends[:, 1])
    track_check = track_check or check
    batch = np.concatenate([o.poses[1:] for o in options if not o.track])
    codes_arcs = np.asarray(check(batch), int) if len(batch) else np.zeros(0, int)
    reasons: dict[str, int] = {}
    verdicts: list[int | None] = []
    at = 0
    for o in options:
        if o.track:
            c = np.asarray(track_check(o.poses[1:]), int)
        else:
            c = codes_arcs[at:at + len(o.poses) - 1]
            at += len(o.poses) - 1
        verdicts.append(_refusal(o, c))
        if verdicts[-1] is not None:
            _count(reasons, o, verdicts[-1])
    passing = sorted((i for i, v in enumerate(verdicts) if v is None and math.isfinite(cost[i])),
                     key=lambda j: (not options[j].track, cost[j]))
    while passing and verify > 0 and body is not None:
        o = options[passing[0]]
        refused = _refusal(o, np.asarray((track_check if o.track else check)(densify(o.poses, verify, body)), int))
        if refused is None:
            break
        passing.pop(0)
        _count(reasons, o, refused)
    if not passing:
        what = ", ".join(f"{n} {k}" for k, n in sorted(reasons.items(), key=lambda kv: -kv[1])) or "no way to the goal"
        return Choice("blocked", f"no reverse section passes ({what})", np.zeros((0, 3)), np.zeros((0, 3)),
                      total=len(options), reasons=reasons)
    i = passing[0]
    o = options[i]
    name = "the track back" if o.track else f"a reverse arc of curvature {o.curvature:.2f} 1/m"
    return Choice("drive", f"{name} ({o.length:.2f} m) passes", o.poses, o.poses, i, i, float(cost[i]),
                  len(options), len(batch), len(options), [], reasons, curvature=o.curvature, length=o.length,
                  backward="track" if o.track else "arc")


def _refusal(o: ReverseOption, codes: np.ndarray) -> int | None:
    """The verdict at ``o``'s first failing pose, or None: the track back fails only on a limit
    exceeded (ground unknown to its check does not refuse it), a reverse arc on anything not safe."""
    bad = np.flatnonzero((codes > 0) if o.track else (codes != SAFE))
    return int(codes[bad[0]]) if len(bad) else None


def _count(reasons: dict[str, int], o: ReverseOption, verdict: int) -> None:
    key = f"{'track back' if o.track else 'reverse arc'} {verdict_name(verdict)}"
    reasons[key] = reasons.get(key, 0) + 1


@dataclass
class DeadEnd:
    """Where the rover found no way on: the ground within ``radius`` of (``x``, ``y``) costs more
    to cross until frames from outside cover it. ``mark``: the map's frame count after which a
    frame that touches the disc from far enough counts as new evidence."""

    x: float
    y: float
    radius: float
    mark: int

    def expired(self, pose: Sequence[float], stamp: np.ndarray, geom: GridGeometry, frames: int,
                clear: float) -> bool:
        """Whether frames from outside the pocket have covered half its ground since ``mark``
        (``stamp``: per cell of ``geom`` the frame that last touched it). While the rover stands
        within ``clear`` of the disc the mark moves on: those frames are the pocket's own."""
        if math.hypot(pose[0] - self.x, pose[1] - self.y) < self.radius + clear:
            self.mark = frames
            return False
        rows, cols = _disc(geom, self.x, self.y, self.radius)
        if not len(rows):
            return True
        return bool(np.mean(stamp[rows, cols] > self.mark) >= 0.5)


def _disc(geom: GridGeometry, x: float, y: float, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of ``geom``'s cells whose centres lie within ``radius`` of (x, y)."""
    c0 = max(0, int(math.floor((x - radius - geom.xmin) / geom.cell)))
    c1 = min(geom.width, int(math.ceil((x + radius - geom.xmin) / geom.cell)))
    r0 = max(0, int(math.floor((geom.ymax - y - radius) / geom.cell)))
    r1 = min(geom.height, int(math.ceil((geom.ymax - y + radius) / geom.cell)))
    if r1 <= r0 or c1 <= c0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    rr, cc = np.mgrid[r0:r1, c0:c1]
    cx, cy = geom.xmin + (cc + 0.5) * geom.cell, geom.ymax - (rr + 0.5) * geom.cell
    inside = np.hypot(cx - x, cy - y) <= radius
    return rr[inside], cc[inside]


def dead_end_penalty(dead_ends: Sequence[DeadEnd], per_metre: float) -> Callable[[np.ndarray], np.ndarray] | None:
    """The dead ends' cost per metre at points (N, 2), for a candidate path crossing them (each
    dead end's disc adds ``per_metre``; None: no dead end)."""
    if not dead_ends or per_metre <= 0:
        return None
    centres = np.array([(d.x, d.y) for d in dead_ends])
    radii = np.array([d.radius for d in dead_ends])

    def penalty(xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float).reshape(-1, 2)
        inside = np.hypot(xy[:, None, 0] - centres[None, :, 0], xy[:, None, 1] - centres[None, :, 1]) <= radii
        return per_metre * inside.sum(axis=1)

    return penalty


def add_dead_ends(cost: np.ndarray, geom: GridGeometry, dead_ends: Sequence[DeadEnd], per_metre: float
                  ) -> np.ndarray:
    """``cost`` (per metre over ``geom``, :func:`.candidates.coarse_costs`) with ``per_metre``
    added on every cell within a dead end's disc (at least the cell it lies in); walls stay."""
    if not dead_ends or per_metre <= 0:
        return cost
    out = np.array(cost, float, copy=True)
    for d in dead_ends:
        rows, cols = _disc(geom, d.x, d.y, max(d.radius, geom.cell / 2))
        if not len(rows):
            r, c = geom.cell_of(d.x, d.y)
            if not (0 <= r < geom.height and 0 <= c < geom.width):
                continue
            rows, cols = np.array([r]), np.array([c])
        out[rows, cols] += per_metre
    return out
