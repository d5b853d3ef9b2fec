"""The see loop's planner on its bounds map (``navigate.see_gate bounds``): Perseverance's ENav
choice, one section at a time.

Each step the rover stands (or has just driven a section) and
:func:`prox_workflows.algorithms.candidates.choose` ranks the arc tree from its pose by cost and
the cost to go (Dijkstra over the bounds map's 25 cm coarse grid, from the goal), then runs the
vehicle check down that list until a candidate passes; the rover drives that candidate's first
section only (a turn on the spot and an arc of at most ``CandidateParams.section``), seeing as it
goes, and chooses again. The check is the chance constraint on the map's per-cell statistics
(``see_check chance``: :func:`.candidates.posterior_check`) or the worst case on its bounds
(``bounds``). What the chooser answers decides what the rover does:

- *drive*: the section, every pose of it judged safe on the map of that moment. While it drives,
  each cycle's frame goes into the map, and the poses of the section still ahead are judged again
  where a frame touched their ground since; one that fails stops the rover (an ``EVENT
  kind=hazard level=stop`` with ``reason vehicle`` or ``unknown``) and the next choice is made from
  where it stands.
- *look*: the best way runs over ground no frame has bounded: the rover looks there (one frame
  tilted to it), then round at the PTU's lowest tilt, before any worse way is driven. A look that
  shows nothing new is not repeated from the same place; the choice is then made with looking
  priced out, and ground still unseen is a failure like any other.
- *blocked*: every candidate fails on the body's limits (or the goal has no way to it on the
  coarse grid). Once the rover has looked round where it stands, it is a dead end, as are unseen
  ground no look shows and ``STALL_SECTIONS`` sections without progress. With
  ``see.retreat.retreats`` above 0 the rover backs out (:mod:`prox_workflows.algorithms.retreat`:
  along its last arc, whose ground it drove, or on a reverse arc its check passes), leaves a cost
  on the dead end's ground for the cost to go, and chooses again. Past that many retreats before
  the rover stands ``see.retreat.regain`` m closer to the goal than where their count began, or
  with no reverse section that passes, it is a safe stop: the job ends ``E_DATA`` with the
  reason, the count of failures by limit and the retreats made.

Each candidate's look-ahead beyond its section refuses it where it fails (or, with
:class:`CandidateParams` ``ahead_cost`` above 0, prices it): it is judged on the posterior's best
estimate (``see_ahead best``), or with the section's own check (``see_ahead chance``, at about
twice a choice's CPU).

No Dem2Hazard threshold decides where the wheels go, and no verdict is kept: a refusal concerns
the map it was made on, and the next choice judges the pose again on the map as it then is. A dead
end is a cost, not a verdict, and it expires once frames from outside it cover its ground.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.rover import Motion
from prox_workflows.algorithms.candidates import (
    LOOK_GROUND,
    SAFE,
    UNKNOWN,
    CandidateParams,
    Check,
    Choice,
    CostToGo,
    best_check,
    bounds_check,
    choose,
    coarse_costs,
    cost_to_go,
    crop,
    nearest_refusal,
    over_rays,
    posterior_check,
    verdict_name,
)
from prox_workflows.algorithms.chance import ChanceParams, posterior
from prox_workflows.algorithms.coarse_memory import CoarseMemory
from prox_workflows.algorithms.retreat import (
    DeadEnd,
    RetreatBudget,
    add_dead_ends,
    choose_reverse,
    dead_end_penalty,
    reverse_options,
)
from prox_workflows.algorithms.vehicle import densify, reach
from prox_workflows.algorithms.waypoints import Waypoints, make_waypoints

from ..protocol import ProtocolError

if TYPE_CHECKING:
    from prox_workflows.algorithms.bounds_map import BoundsMap

    from .see import SeeingDriver
    from .see_strategy import SeeStrategy

LOOKS = 6  # looks before one drive at most: past them the choice is made with looking priced out
PRICED_OUT = 1e6  # m: the look cost that makes a look the answer only when no candidate passes
STALL_SECTIONS = 12  # sections in a row that bring the rover no STALL_GAIN closer by the cost to go
STALL_GAIN = 0.1  # m
REVISIT = 0.25  # m: a section ending this close to where the rover stood since its best closes a loop
WAYPOINT_STEP = 0.2  # m between the waypoints a GNC is sent for a section
GUIDE_PAD = 4.0  # m round the mission's start and goal the coarse guidance covers (past it: the straight line)
GUIDE_CELL = 0.25  # m: the coarse grid the cost to go runs on (coarse_costs'), kept over the whole mission
WINDOW_SLACK = 1.0  # m the rover strays from the bounds window's centre before the window recentres
TRACK_STILL = 0.02  # m: the rover stands where its last arc ended (the track back starts there)
TRACK_TURN = 1.0  # deg: and faces as it did
WINDOW_MARGIN = 0.5  # m past the farthest a choice or a frame reaches: a cell's spread, a coarse cell


def judged_reach(params: CandidateParams, body: Any) -> float:
    """How far from the rover's pose a choice reads the bounds map: the candidates' section and
    look-ahead, the body's reach round their poses, and a cell's spread."""
    return params.section + params.beyond + reach(body) + 0.1


def window_half(see: Any, body: Any, head: Any) -> float:
    """Half the side of the bounds window that follows the rover (``see``: the see loop's config,
    ``head``: the head's calibration): the farthest a choice reads (:func:`judged_reach`), a
    standing look reaches (the ground the body covers driving ``see_look_drive`` and as far again)
    or a frame lands (``see_max_range`` from the mast), plus the slack the rover strays from its
    centre and a margin. Within it, every cell the chooser judges and every frame bounds is held."""
    mast = math.hypot(head.ptu_base[0], head.ptu_base[1])
    looks = 2 * see.look_drive + body.length
    return max(judged_reach(see.chooser, body), looks, see.max_range + mast) + WINDOW_SLACK + WINDOW_MARGIN


def map_check(bounds: BoundsMap, box: tuple[float, float, float, float], body: Any, how: str,
              chance: ChanceParams) -> Check:
    """The vehicle check over ``box`` (xmin, ymin, xmax, ymax) of the bounds map as a
    :data:`~prox_workflows.algorithms.candidates.Check`: ``chance`` on the cells' posteriors (the
    map's per-cell statistics: the mean's horizontal error along its rays averaged as its height
    is, and the slope's steepest direction for the rays'), ``best`` on their best estimate alone
    (no draws), ``framed`` on the best estimate of the cells a frame bounded only (the rest
    unknown: the track back's check, :func:`track_check`), ``bounds`` the worst case on its bounds."""
    stats, g = bounds.statistics(*box)
    if how == "chance":
        return posterior_check(posterior(stats, g, bounds.params.k, chance), g, body, chance)
    if how == "best":
        return best_check(posterior(stats, g, bounds.params.k, chance), g, body)
    if how == "framed":
        return track_check(posterior(stats, g, bounds.params.k, chance), stats["framed"], g, body)
    return bounds_check((stats["lower"], stats["upper"]), g, body)


def track_check(post: Any, framed: np.ndarray, g: Any, body: Any) -> Check:
    """The check of the track back: the posterior's best estimate where a frame bounded the cell,
    unknown elsewhere (the set-down's prior, the wheels' contacts, a ray's ceiling). The body stood
    on every pose of the track, so what can refuse it is ground that changed since, and only a
    frame shows a change: a prior is a guess at ground no frame saw (the start's blind disc filled
    on from the ring round it), and judged as ground it refuses poses the wheels drove over. A
    pose over unframed ground is unknown, which the track back takes (never a limit exceeded),
    judged cell by cell on the frames' heights (bounds read cellwise, lower and upper alike)."""
    surface = np.where(framed, post.mean, np.nan).astype(np.float32)
    return bounds_check((surface, surface.copy()), g, body)


def guidance(bounds: BoundsMap, goal: tuple[float, float], body: Any, params: CandidateParams,
             guide: CoarseMemory | None = None, dead_ends: Sequence[DeadEnd] = (), dead_end_cost: float = 0.0
             ) -> CostToGo:
    """The cost to go over the coarse grid (``guide``'s, the whole mission with what the map now
    says written in; None: the map's own), a dead end's disc priced ``dead_end_cost`` per metre
    more."""
    if guide is None:
        cost, cg = coarse_costs(bounds.whole(), bounds.geometry, body, **params.coarse)
    else:
        guide.update(bounds.whole(), bounds.geometry, body, **params.coarse)
        cost, cg = guide.costs()
    return cost_to_go(add_dead_ends(cost, cg, dead_ends, dead_end_cost), cg, goal)


def choose_from(bounds: BoundsMap, pose: tuple[float, float, float], goal: tuple[float, float], body: Any,
                how: str, params: CandidateParams, chance: ChanceParams, guide: CoarseMemory | None = None, *,
                ahead: str = "best", dead_ends: Sequence[DeadEnd] = (), dead_end_cost: float = 0.0,
                explain: bool = False) -> tuple[Choice, float]:
    """The chooser's answer from ``pose`` toward ``goal`` on the bounds map as it is now, and the
    cost to go from ``pose``: the cost to go over the coarse grid (:func:`guidance`), the
    candidates ranked and checked on the window they reach. ``ahead`` (``see_ahead``): ``best``
    judges the look-aheads on the best estimate, ``chance`` with the section's check. ``explain``:
    a blocked choice's reason also names the candidate nearest to passing (:func:`nearest_refusal`,
    seconds of CPU: asked for where a blocked choice ends the mission)."""
    ctg = guidance(bounds, goal, body, params, guide, dead_ends, dead_end_cost)
    r = judged_reach(params, body)
    box = (pose[0] - r, pose[1] - r, pose[0] + r, pose[1] + r)
    stats, wg = bounds.statistics(*box)
    lookahead = None
    if how == "chance":
        post = posterior(stats, wg, bounds.params.k, chance)
        check = posterior_check(post, wg, body, chance)
        if ahead == "best":  # the look-aheads only rank: one check on the best estimate, no draws
            lookahead = best_check(post, wg, body)
    else:
        check = bounds_check((stats["lower"], stats["upper"]), wg, body)
    rays = over_rays(stats["mean"], stats["ceiling"], wg, body) if params.ray_looks else None
    choice = choose(pose, (stats["lower"], stats["upper"]), wg, body, ctg, check, params, lookahead,
                    dead_end_penalty(dead_ends, dead_end_cost), rays)
    if explain and how == "chance" and choice.status == "blocked" and \
            (near := nearest_refusal(post, wg, body, pose, choice.failures, params, chance)):
        choice = dataclasses.replace(choice, reason=f"{choice.reason} ({near})")
    return choice, float(ctg.at(np.array([pose[0]]), np.array([pose[1]]))[0])


def reasons(choice: Choice) -> str:
    """The failures of the candidates checked, by part and limit, most first."""
    parts = sorted(choice.reasons.items(), key=lambda kv: -kv[1])
    return ", ".join(f"{n} {k}" for k, n in parts) or "none checked"


class Chooser:
    """The see strategy's legs on the bounds map: one choice, then its section driven."""

    def __init__(self, strategy: SeeStrategy) -> None:
        self.s = strategy
        self.d: SeeingDriver = strategy.driver
        self.params = self.d.p.chooser
        self.chance = self.d.p.chance
        self.rounds: list[tuple[float, float]] = []  # where the rover looked round
        self.best = math.inf  # the least cost to go the rover stood at
        self.since_best = 0  # sections driven since
        self.stood: list[tuple[float, float]] = []  # where each section since the best began
        self.retreat = self.d.p.retreat
        self.budget = RetreatBudget(self.retreat)
        self.dead_ends: list[DeadEnd] = []  # where the rover found no way on, priced until seen from outside
        # the arcs driven forward since the last reverse: (curvature, m) and the pose (believed) it ended at
        self.arcs: list[tuple[tuple[float, float], tuple[float, float, float]]] = []
        self.started = False  # the start's turn (the hazard cameras' look round the body) is behind
        # the cost to go's coarse grid over the whole mission: the bounds map is a window round the rover
        self.guide = CoarseMemory.covering(strategy.cover, GUIDE_PAD, GUIDE_CELL)

    def scanned(self) -> None:
        """A 360-degree scan was made where the rover stands (the scan loop's, or the localiser's):
        its views make the 5 cm maps only, so the rover looks round for the bounds map too. Its
        frames (4 a view, at the scan's tilts) are noisier than a look's (8, from the lowest tilt
        out), and ground they had judged would not be looked at again (docs/NAVIGATE_BENCH.md, "The
        scan loop on the chooser")."""
        self._look_round(self.d.pose())

    def _looked_round_here(self, pose: tuple[float, float, float]) -> bool:
        return any(math.hypot(pose[0] - x, pose[1] - y) < 0.3 for x, y in self.rounds)

    def _look_round(self, pose: tuple[float, float, float]) -> None:
        """A standing look all round: a turn on the spot may face any way, and toward the goal
        alone leaves the chooser's turns judged on unseen ground (marsyard mission 0's start)."""
        self.rounds.append((pose[0], pose[1]))
        self.d.look_round()

    def _choose(self, pose: tuple[float, float, float], look_cost: float | None,
                ray_looks: bool = True) -> tuple[Choice, float]:
        params = self.params if look_cost is None else dataclasses.replace(self.params, look_cost=look_cost)
        if not ray_looks:
            params = dataclasses.replace(params, ray_looks=False)
        bounds = self.d.bounds
        self.d.app.bus.publish("bounds", bounds=bounds, replan=True)  # what this choice reads
        self.dead_ends = [e for e in self.dead_ends
                          if not e.expired(pose, bounds.stamp, bounds.geometry, bounds.frames, self.retreat.clear)]
        t0, c0 = time.monotonic(), time.process_time()
        try:
            return choose_from(bounds, pose, self.s.mission.goal, self.d.body, self.d.p.vehicle, params,
                               self.chance, self.guide, ahead=self.d.p.ahead, dead_ends=self.dead_ends,
                               dead_end_cost=self.retreat.cost,
                               explain=self.budget.spent)
        finally:
            self.s.stats.replanned(t0, c0)

    def _track_back(self, pose: tuple[float, float, float]) -> tuple[float, float] | None:
        """The last arc driven (curvature, m) where the rover stands at its end as it ended it, else
        None. Reversed from any other pose it is not the track: a turn on the spot since (a section
        stopped after its turn, the turn before the arc a track back has just undone) swings it
        round onto ground the body never stood on, which the track back's check does not refuse."""
        if not self.arcs:
            return None
        arc, (x, y, heading) = self.arcs[-1]
        turned = abs((pose[2] - heading + 180.0) % 360.0 - 180.0)
        return arc if math.hypot(pose[0] - x, pose[1] - y) <= TRACK_STILL and turned <= TRACK_TURN else None

    def set_down_hint(self, pose: tuple[float, float, float]) -> str:
        """What an operator can do about a safe stop where the rover was set down and has not left
        (its turns sweep the set-down's guess at the ground round the body, which no camera shows):
        a short straight drive of the GNC's own, and navigate again on this map. Empty elsewhere,
        on the map the last navigate left where the rover still stands, or with keep_moved 0."""
        x0, y0 = self.s.cover[0]
        if not self.s.sets_down or self.d.p.keep_moved <= 0 or math.hypot(pose[0] - x0, pose[1] - y0) >= reach(self.d.body):
            return ""
        return ("; the rover has not left where it was set down, and the ground under and round its body there is "
                "the set-down's guess, which no camera shows: the GNC may back it straight (about 0.6 m) on its own "
                "judgement, report its pose and send navigate again, which sets down on this navigate's map "
                f"(navigate.see_keep_moved, {self.d.p.keep_moved:g} m)")

    def _back_out(self, leg: int, pose: tuple[float, float, float], why: str) -> None:
        """A dead end at ``pose`` (``why``: the sentence the safe stop would have said): back out of
        it on the cheapest reverse section that passes, its ground priced for the cost to go; a
        safe stop (E_DATA) once the budget's retreats are made (:class:`RetreatBudget`) or none
        passes."""
        if self.budget.spent:
            raise ProtocolError("E_DATA", f"{why}; {self.budget} (navigate.see.retreat.retreats)"
                                          f"{self.set_down_hint(pose)}")
        bounds = self.d.bounds
        self.dead_ends.append(DeadEnd(pose[0], pose[1], self.retreat.radius, bounds.frames))
        options = reverse_options(pose, self._track_back(pose), self.retreat, self.params.max_curvature,
                                  self.params.step)
        t0, c0 = time.monotonic(), time.process_time()
        try:
            ctg = guidance(bounds, self.s.mission.goal, self.d.body, self.params, self.guide, self.dead_ends,
                           self.retreat.cost)
            pts = np.concatenate([o.poses for o in options])
            pad = reach(self.d.body) + 0.1
            box = (pts[:, 0].min() - pad, pts[:, 1].min() - pad, pts[:, 0].max() + pad, pts[:, 1].max() + pad)
            check = map_check(bounds, box, self.d.body, self.d.p.vehicle, self.chance)
            track = map_check(bounds, box, self.d.body, "framed", self.chance)
            choice = choose_reverse(pose, options, check, ctg, track, self.d.body, self.params.verify_step)
        finally:
            self.s.stats.replanned(t0, c0)
        if choice.status != "drive":
            raise ProtocolError("E_DATA", f"{why}; backing out: {choice.reason} ({self.budget})"
                                          f"{self.set_down_hint(pose)}")
        self.s.stats.retreats += 1
        self.budget.made += 1
        self.s.mission.progress(leg, 1, 1, f"dead end at ({pose[0]:.2f}, {pose[1]:.2f}): backing out "
                                           f"({self.budget.made} of {self.retreat.retreats}) on {choice.reason}",
                                "plan")
        if choice.backward == "track":
            self.arcs.pop()
        else:  # off the track: the arcs before it no longer lead back from where it stands
            self.arcs.clear()
        self.best, self.since_best, self.stood = math.inf, 0, []
        self.drive(leg, choice)

    def drive_on(self, leg: int) -> bool:
        """Choose and drive one section (looking first where the choice asks); a blocked choice
        after a look round here is a safe stop (E_DATA with its reason)."""
        d, job = self.d, self.s.job
        pose = d.pose()
        goal = self.s.mission.goal
        self.budget.stand(math.hypot(goal[0] - pose[0], goal[1] - pose[1]))
        if not self.rounds:  # the set-down: the ground round the rover from the blind disc out
            self._look_round(pose)
        moved = self.s.moved
        left = "" if moved is None else \
            f" on the map the last navigate left ({d.bounds.frames} frames), {moved:.2f} m from where it left the rover"
        if d.set_down_pending:
            m = self.s.set_down_on_ring()
            self.s.mission.progress(leg, 1, 1, f"set down on {m}{left}", "plan")
        elif self.s.kept and not self.started:
            said = "no set-down" if moved is None else f"{moved:.2f} m from where it left the rover, set down again"
            self.s.mission.progress(leg, 1, 1, f"the ground round the rover as the last navigate left it "
                                               f"({d.bounds.frames} frames), {said}", "plan")
        if not self.started:  # after the set-down: its prior is what the turn is judged on
            self.started = True
            self._start_turn(leg)
            pose = d.pose()
        look_cost: float | None = None
        ray_looks = True
        for _ in range(LOOKS + 2):
            job.check()
            choice, togo = self._choose(pose, look_cost, ray_looks)
            if choice.status == "drive":
                break
            if choice.status == "look":
                x, y = choice.look_at or (pose[0], pose[1])
                if look_cost is None and d.look_at(x, y, pose, LOOK_GROUND[choice.look_for or "unseen"]):
                    continue
                if choice.look_for == "ray":  # looked from here: the ground a ray bounds is judged as it is
                    ray_looks = False
                    continue
                if not self._looked_round_here(pose):
                    self._look_round(pose)
                    continue
                if look_cost is None:  # looking from here shows no more: choose among what it shows
                    look_cost = PRICED_OUT
                    continue
                self._back_out(leg, pose, f"unseen ground ahead that no look from here shows: the best way "
                                          f"on runs over ({x:.2f}, {y:.2f}), no frame bounds it after a look "
                                          f"round from ({pose[0]:.2f}, {pose[1]:.2f}); failures: "
                                          f"{reasons(choice)}")
                return True
            if not self._looked_round_here(pose):  # blocked: look round before giving up
                self._look_round(pose)
                continue
            self._back_out(leg, pose, f"no way on within the body's limits: {choice.reason} from "
                                      f"({pose[0]:.2f}, {pose[1]:.2f}) after a look round; failures: "
                                      f"{reasons(choice)}")
            return True
        else:
            self._back_out(leg, pose, f"no way on: {LOOKS} looks from ({pose[0]:.2f}, {pose[1]:.2f}) show no "
                                      "section that passes")
            return True
        if togo < self.best - STALL_GAIN:
            self.best, self.since_best, self.stood = togo, 0, []
        else:
            self.since_best += 1
            if self.since_best >= STALL_SECTIONS:
                self._back_out(leg, pose, f"no progress: {STALL_SECTIONS} sections from ({pose[0]:.2f}, "
                                          f"{pose[1]:.2f}) brought the rover no {STALL_GAIN:g} m closer by "
                                          f"the cost to go ({togo:.2f} m)")
                return True
            self._close_loop(leg, pose, choice)
        self.stood.append((pose[0], pose[1]))
        self.drive(leg, choice)
        self.s.stats.replans += 1
        return True

    def _close_loop(self, leg: int, pose: tuple[float, float, float], choice: Choice) -> None:
        """A section that brings the rover back to where it stood since its best, no closer, shows
        that the way on from here was the way back: where it stands is priced as a dead end (no
        reverse is driven: the section is the way out), so that the place it returns to does not
        send it here again. Without it the rover shuttles between a place whose best estimate looks
        open and one whose own check refuses every way on, until :data:`STALL_SECTIONS` run out."""
        end = choice.poses[-1]
        if any(math.hypot(e.x - pose[0], e.y - pose[1]) <= REVISIT for e in self.dead_ends):
            return
        for x, y in self.stood:
            if math.hypot(x - pose[0], y - pose[1]) > REVISIT and math.hypot(x - end[0], y - end[1]) <= REVISIT:
                self.dead_ends.append(DeadEnd(pose[0], pose[1], self.retreat.radius, self.d.bounds.frames))
                self.s.mission.progress(leg, 1, 1, f"dead end at ({pose[0]:.2f}, {pose[1]:.2f}): the way on "
                                                   f"leads back to ({x:.2f}, {y:.2f}), no closer", "plan")
                return

    def _start_turn(self, leg: int) -> None:
        """With the body's hazard cameras on, the start's turn on the spot: ``see_start_turn`` at a
        time until the pairs have looked all round, a frame of every pair at each heading (and
        the front pair's every cycle of the turn). Between the body and the mast's blind disc no
        tilt of the mast shows the ground; the pairs do, from about 0.1 m past the body out, and where
        they bound a cell the set-down's prior yields to them: the prior is left on the ground no
        camera saw (under the body, and a band of about 0.1 m round it). Each step is judged first
        on the map as it is, prior included (the start is where the rover was set down to turn:
        the missions' starts are drawn so); a step that fails ends the turn, and the prior stays
        where it was not seen. A GNC is sent each step as a section of one waypoint, where the
        rover stands with the heading to turn to."""
        d = self.d
        step = d.p.start_turn
        if not d.hazcams or step <= 0.0:
            return
        headings = math.ceil(360.0 / (len(d.hazcams) * step) - 1e-9)
        for _ in range(headings - 1):
            pose = d.pose()
            poses = densify(np.array([pose, (pose[0], pose[1], pose[2] + step)]),
                            self.params.verify_step or self.params.step, d.body)
            r = reach(d.body) + 0.1
            codes = np.asarray(map_check(d.bounds, (pose[0] - r, pose[1] - r, pose[0] + r, pose[1] + r), d.body,
                                         d.p.vehicle, self.chance)(poses))
            bad = np.flatnonzero(codes != SAFE)
            if len(bad):
                at = poses[bad[0]]
                self.s.mission.progress(leg, 1, 1, f"the start's turn ends: {step:g} deg more fails "
                                                   f"({verdict_name(int(codes[bad[0]]))}) at heading {at[2]:.0f} deg",
                                        "drive")  # (a second "plan" line after the set-down's is not sent)
                return
            turn = Choice("drive", "the start's turn", poses, poses, turn=step)
            if self.drive(leg, turn, f"turning {step:g} deg on the spot: the hazard cameras see round the body"):
                return
            d.see(d.pan_tilt, tuple(d.hazcams))  # every pair, standing at the new heading

    def drive(self, leg: int, choice: Choice, what: str = "") -> str | None:
        """Drive ``choice``'s section while seeing (the simulated rover steers it; a GNC is sent
        its waypoints and each pose report is a cycle); ``what`` says what it is (default: the
        chooser's candidate). Returns why it stopped short, or None."""
        m, d = self.s.mission, self.d
        xy = choice.poses[:, :2]
        step = max(1, int(round(WAYPOINT_STEP / max(self.params.step, 1e-3))))
        keep = np.unique(np.r_[np.arange(0, len(xy), step), len(xy) - 1])
        if choice.backward:  # the body's headings: the GNC backs along them (drive=reverse)
            wps = _reverse_waypoints(choice.poses[keep])
        else:
            points = _dedup(xy[keep])
            if np.hypot(*(points[-1] - points[0])) <= 1e-6:
                # a turn on the spot alone (the start's): one waypoint, where the rover stands,
                # with the heading it turns to
                wps = make_waypoints(points[:1], start_heading=float(choice.poses[-1, 2]))
            else:
                wps = make_waypoints(points, start_heading=float(choice.poses[0, 2]))
        m.record(xy, wps.xy)
        end = (float(xy[-1, 0]), float(xy[-1, 1]))
        if not choice.backward:
            m.progress(leg, 1, 1, what or f"chose candidate {choice.candidate} (rank {choice.rank + 1} of "
                                          f"{choice.total}, {choice.checked} checked): turn {choice.turn:.0f} deg, "
                                          f"{choice.length:.2f} m to ({end[0]:.2f}, {end[1]:.2f})", "plan")
        since = m.announce(leg, wps, "none", reverse=bool(choice.backward))
        pilot = SectionPilot(self, choice, m.track)
        start_of_leg = len(m.track)
        if not pilot.gazing:  # a gazing pilot points the mast itself, while the wheels turn
            d.point_forward()
        m.drive(pilot, since, end)
        if pilot.stopped is not None:
            m.progress(leg, 1, 1, f"stopped: {pilot.stopped}", "drive")
        if not choice.backward:
            # from the row before the section's: where the rover stood when it set off
            arc = _driven_arc(np.asarray(m.track.rows[max(0, start_of_leg - 1):], float).reshape(-1, 3))
            if arc is not None:
                self.arcs.append((arc, d.pose()))
        self.s.localise(leg, m.track.xy(start_of_leg))
        return pilot.stopped


def _driven_arc(rows: np.ndarray) -> tuple[float, float] | None:
    """The arc the track rows of one section show driven (after its turn on the spot): its
    curvature (1/m, the heading's change over the metres) and its metres; None if it did not
    move. The track is where the body went (the simulator's truth, the GNC's reports), so the
    track back follows it, not the section as chosen."""
    if len(rows) < 2:
        return None
    steps = np.hypot(*np.diff(rows[:, :2], axis=0).T)
    moved = np.flatnonzero(steps > 1e-4)
    metres = float(steps.sum())
    if not len(moved) or metres < 1e-3:
        return None
    turned = (rows[-1, 2] - rows[moved[0], 2] + 180.0) % 360.0 - 180.0
    return math.radians(turned) / metres, metres


def _reverse_waypoints(poses: np.ndarray) -> Waypoints:
    """A reverse section's waypoints: each with the body's heading there (opposite to the way it
    moves), no turn on the spot, and the leg's length to the next."""
    xy = poses[:, :2]
    legs = np.hypot(*np.diff(xy, axis=0).T)
    return Waypoints(xy, (poses[:, 2] + 180.0) % 360.0 - 180.0, np.zeros(len(xy)), np.r_[legs, 0.0])


def turn_faces(heading: float, turn: float) -> list[float]:
    """The headings a turn on the spot of ``turn`` degrees (counter-clockwise positive) from
    ``heading`` faces one after the other: the rover turns to face each the shortest way, so a turn
    of more than 90 degrees faces its middle first. The check judged the turn's own way round, and
    a half turn (the candidates' 180 degrees) is either way by the shortest: the body would sweep
    the other half circle, ground no check judged. None for a turn under half a degree."""
    if abs(turn) < 0.5:
        return []
    if abs(turn) <= 90.0:
        return [heading + turn]
    return [heading + turn / 2, heading + turn]


def _dedup(xy: np.ndarray) -> np.ndarray:
    """Waypoints without repeats (a turn on the spot stands at one point)."""
    keep = np.r_[True, np.hypot(*np.diff(xy, axis=0).T) > 1e-6]
    out = xy[keep]
    return out if len(out) > 1 else np.vstack([out, out[-1:]])


class SectionPilot:
    """One section for :meth:`drivers.rover.Rover.drive`: the turn on the spot, then the arc in
    cycles of ``see_period``, a frame and the check of the section's rest every cycle."""

    def __init__(self, chooser: Chooser, choice: Choice, track: Any) -> None:
        self.c = chooser
        self.d = chooser.d
        self.track = track
        self.poses = choice.poses  # from the rover's pose: the turn's poses, then the arc's
        n_turn = int(np.count_nonzero(np.hypot(*(choice.poses[:, :2] - choice.poses[0, :2]).T) < 1e-9)) - 1
        self.n_turn = max(0, n_turn)
        start = choice.poses[0]
        self.faces = turn_faces(float(start[2]), choice.turn)  # the headings the turn faces in turn
        self.turned = not self.faces
        self.curvature = choice.curvature
        self.length = choice.length
        self.s = np.r_[np.zeros(self.n_turn + 1),
                       np.cumsum(np.hypot(*np.diff(choice.poses[self.n_turn:, :2], axis=0).T))]
        self.driven = 0.0
        self.path = choice.path
        self.frames = self.d.bounds.frames  # the map the section was judged on
        self.backward = choice.backward
        # backing out, the mast stays forward: it cannot pan behind
        self.gazing = self.d.rover.steers and not self.backward and self.d.gazes
        self.stopped: str | None = None
        self.hazard: dict[str, Any] | None = None
        self.aimed = False  # the next frame's look was sent with the last motion (the mast slews meanwhile)

    def moved(self, truth: tuple[float, float, float], end: bool) -> None:
        self.track.add(truth, end)

    def _ahead(self) -> np.ndarray:
        """The section's poses still to drive: past the one the rover stands on, which the choice
        never judged either (a candidate's poses start past the rover's). The pose it stands on is
        no reason to stop, as stopping leaves the rover on it: judged, a spread the frames taken
        standing there give it would stop every section set off from it, over and over."""
        if not self.turned:
            return self.poses[1:]
        return self.poses[self.n_turn:][self.s[self.n_turn:] > self.driven + 1e-6]

    def _path_ahead(self, pose: tuple[float, float, float]) -> np.ndarray:
        """The chosen path's points still ahead of ``pose`` (past the one nearest it): the gaze
        measures along what is still to drive, and from the section's start it would look back."""
        xy = self.path[:, :2]
        i = int(np.argmin(np.hypot(xy[:, 0] - pose[0], xy[:, 1] - pose[1])))
        return xy[i + 1:] if i + 1 < len(xy) else xy[-1:]

    def _recheck(self, pose: tuple[float, float, float]) -> tuple[int, np.ndarray] | None:
        """The first pose of the section's rest that fails on the map as it is now (its verdict and
        the pose), where a frame touched the ground under that rest since it was judged; None: all
        pass, or nothing there changed."""
        ahead = np.vstack([np.array([pose]), self._ahead()])
        if len(ahead) == 1:  # at the section's end: nothing left to drive
            return None
        d = self.d
        pad = reach(d.body) + 0.05
        box = (ahead[:, 0].min() - pad, ahead[:, 1].min() - pad, ahead[:, 0].max() + pad, ahead[:, 1].max() + pad)
        bounds = d.bounds
        _, sl = crop(bounds.geometry, *box)
        if sl is None or not (bounds.stamp[sl] > self.frames).any():
            return None
        self.frames = bounds.frames
        how = "framed" if self.backward == "track" else d.p.vehicle  # as it was chosen
        codes = np.asarray(map_check(bounds, box, d.body, how, self.c.chance)(ahead[1:]))
        # the track back's ground was under the body: unknown to the map is no reason to stop there
        bad = np.flatnonzero((codes > 0) if self.backward == "track" else (codes != SAFE))
        return None if not len(bad) else (int(codes[bad[0]]), ahead[1 + bad[0]])

    def _stop(self, verdict: int, at: np.ndarray, pose: tuple[float, float, float]) -> None:
        reason = "unknown" if verdict == UNKNOWN else "vehicle"
        self.stopped = (f"the pose ({at[0]:.2f}, {at[1]:.2f}, {at[2]:.0f} deg) of the section ahead fails "
                        f"({verdict_name(verdict)}) on the frames since it was chosen")
        self.hazard = self.d._stop_event(float(at[0]), float(at[1]), pose, reason)

    def next(self, pose: tuple[float, float, float]) -> Motion | None:
        d = self.d
        if self.gazing and not self.aimed and not d.p.start_look and d.standing(pose[0], pose[1]):
            # the section's start where the last frame was taken and the section chosen on it: the
            # first frame comes after the first motion, its look sent with it
            seen, bad = pose, None
        else:
            if self.gazing and not self.aimed:  # the section's first frame: a look along it, standing
                d.gaze(pose, self._path_ahead(pose))
            d.settle()
            seen, t1 = d.see(d.pan_tilt, frames=d.p.drive_frames)
            d.job.check()
            bad = self._recheck(seen)
            d.stats.cycle(t1, d.cpu1)
        if not d.rover.steers:  # the GNC drives: a failing pose ahead is a stop EVENT, once
            if bad is not None and self.hazard is None:
                self._stop(*bad, seen)
            return None
        if bad is not None:
            self._stop(*bad, seen)
            return None
        d._clear()
        if not self.turned:
            h = math.radians(self.faces.pop(0))
            self.turned = not self.faces
            motion = Motion.face(seen[0] + math.cos(h), seen[1] + math.sin(h))
        else:
            left = self.length - self.driven
            if left <= 1e-3:
                return None
            speed, turn_rate = d.rover.speeds()
            if self.curvature:  # no faster than the turn rate drives the arc's curvature
                speed = min(speed, math.radians(turn_rate) / abs(self.curvature))
            dt = min(d.p.period, left / speed)
            self.driven += speed * dt
            if self.backward:
                speed = -speed
            motion = Motion.arc(speed, math.degrees(self.curvature * speed), dt)
        if self.gazing:  # the next frame's look, sent now: the mast slews while the wheels turn
            after = motion_end(seen, motion)
            d.gaze(after, self._path_ahead(after), wait=False)
            self.aimed = True
        return motion


def motion_end(pose: tuple[float, float, float], motion: Motion) -> tuple[float, float, float]:
    """Where ``motion`` leaves a rover at ``pose`` (x, y, heading deg) by its own kinematics: a
    turn on the spot faces its target, an arc turns at its rate for its seconds."""
    x, y, h = pose
    if motion.target is not None:
        return x, y, math.degrees(math.atan2(motion.target[1] - y, motion.target[0] - x))
    turn = math.radians(motion.rate * motion.seconds)
    run = motion.speed * motion.seconds
    if abs(turn) < 1e-9:
        dx, dy = run, 0.0
    else:
        r = run / turn
        dx, dy = r * math.sin(turn), r * (1.0 - math.cos(turn))
    c, s = math.cos(math.radians(h)), math.sin(math.radians(h))
    return x + c * dx - s * dy, y + s * dx + c * dy, h + math.degrees(turn)
