"""Whether the body can drive a mission at all: a search with the body itself on the true surface.

A mission is **feasible** when the lattice search (:func:`prox_workflows.algorithms.lattice.search`:
5 cm cells, 16 headings, straights, arcs and turns on the spot) over the scene's true 1 cm surface,
every motion judged by the vehicle check (:func:`prox_workflows.algorithms.vehicle.check_poses`:
wheel, belly and tilt against the body's limits), finds a way to the goal's cell, and that path
then passes the truth check (:func:`rvs_truth.vehicle.vehicle_check`: the path densified to 2 cm,
turns included) with no event. Its **oracle efficiency** is the straight-line distance over the
path's driven length. No map, no threshold: what the body physically cannot do is the only
limit, so this is an upper bound on what any planner of this body can find, where a plan on a
hazard map's window step is a lower one.

The search is weighted A* (:data:`WEIGHT`; exact A* is too slow for a benchmark, see there): the
straight-line heuristic is admissible, and the lazy judging (every :data:`JUDGE_EVERY`-th pose
of a motion, then the found path in full, searched again until it passes) refuses only motions
that are unsafe, so ``exhausted`` proves there is no way on the lattice. A search that meets its
expansion budget proves nothing: the mission is then reported ``budget``, not feasible.

Results are cached per mission in a file under a cache directory, keyed by a hash of the scene,
the seed, the start and goal, every field of the body and the source of the check (its kernel too),
the lattice and this module, so a changed limit or search is never answered from an old result.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from prox_workflows.algorithms import lattice, vehicle
from prox_workflows.algorithms.lattice import EdgeCache, primitives, search
from prox_workflows.algorithms.vehicle import VehicleBody, check_poses
from prox_workflows.grid import GridGeometry

from . import vehicle as truth_vehicle
from .vehicle import TRACK_STEP, vehicle_check

RES = 0.05  # m: the lattice's cell
HEADINGS = 16
JUDGE_EVERY = 4  # the search judges every 4th dense pose of a motion (8 cm of body motion) and its end
# expansions (all lazy re-searches together) past which nothing is proven: a feasible mission of
# 15-20 m takes 1,000-3,000 at WEIGHT in open ground, but up to 154,000 through dense rock (dense
# missions 1 and 3: met 80,000, found at 97,685 and 154,202, 20-26 s with the compiled check)
MAX_EXPANSIONS = 400_000
# the heuristic's inflation, since exact A* is too slow for a benchmark: on marsyard mission 0 it
# expands 339,000 states (524 s on a shared machine) for a path at efficiency 0.979; at 1.1,
# 2,700 for 0.971; at 1.2, 1,234 for 0.966 (25 s); at 1.5, 747 for 0.947. The path found is at
# most WEIGHT times the shortest, so the oracle's efficiency is a lower bound within that factor
WEIGHT = 1.2


def body_reach(body: VehicleBody) -> float:
    """How far the body's farthest point lies from its centre (m): the radius it turns in."""
    hubs = np.abs(np.asarray(body.wheels, float))
    return math.hypot(max(body.length / 2, float(hubs[:, 0].max()) + body.wheel_radius),
                      max(body.width / 2, float(hubs[:, 1].max()) + body.wheel_width / 2))


def oracle(surface: tuple[np.ndarray, GridGeometry, GridGeometry], body: VehicleBody, start: tuple[float, float],
           goal: tuple[float, float], max_expansions: int = MAX_EXPANSIONS, weight: float = WEIGHT) -> dict[str, Any]:
    """The search with ``body`` on ``surface`` (:func:`rvs_truth.surface.truth_surface`) from
    ``start``, facing ``goal``, to ``goal``: ``feasible``, ``efficiency`` (0 when not),
    ``reason`` (``found``; ``exhausted``: no way, proven; ``budget``: undecided), the path's
    driven ``length``, the truth check's ``events`` on it, and what it cost."""
    fine, g, _ = surface
    reach = body_reach(body)
    t0 = time.perf_counter()

    def edge_check(poses: np.ndarray) -> np.ndarray:
        return check_poses(fine, g, poses, body).safe

    # the body stays on the surface (the check takes ground off it as a drop, not as ground), but
    # a start or goal nearer its edge than the reach is searched from or to all the same
    bounds = (min(g.xmin + reach, start[0], goal[0]), min(g.ymin + reach, start[1], goal[1]),
              max(g.xmax - reach, start[0], goal[0]), max(g.ymax - reach, start[1], goal[1]))
    heading = math.degrees(math.atan2(goal[1] - start[1], goal[0] - start[0]))
    prims = primitives(RES, HEADINGS, TRACK_STEP, reach)
    r = search(start, heading, goal, bounds, edge_check, res=RES, prims=prims, judge_every=JUDGE_EVERY,
               weight=weight, max_expansions=max_expansions, cache=EdgeCache())
    out: dict[str, Any] = {"feasible": False, "efficiency": 0.0, "reason": r.reason, "length": None,
                           "expanded": r.expanded, "searches": r.searches, "poses_judged": r.poses_checked,
                           "events": []}
    if r.path is not None:
        # the rover starts facing the goal: its turn on the spot to the lattice's heading is driven too
        poses = np.vstack([[start[0], start[1], heading], r.path.poses])
        events, checked = vehicle_check(poses, surface, body)
        dist = math.hypot(goal[0] - start[0], goal[1] - start[1])
        out.update(feasible=not events, length=round(r.path.length, 3), poses_verified=checked,
                   efficiency=round(dist / r.path.length, 3) if not events and r.path.length > 0 else 0.0,
                   events=[e.describe() for e in events], path=poses.tolist())
        if events:
            out["reason"] = "refused by the truth check"
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def code_version() -> str:
    """A hash of the source that decides a verdict: the vehicle check and its compiled kernel, the
    lattice, the truth check and this module."""
    h = hashlib.sha256()
    for module in (vehicle, lattice, truth_vehicle):
        h.update(Path(module.__file__).read_bytes())
    h.update(Path(vehicle.__file__).with_name("_vehicle_kernel.py").read_bytes())  # read, not imported (numba)
    h.update(Path(__file__).read_bytes())
    return h.hexdigest()[:16]


def default_cache_dir() -> Path:
    """``$RVS_ORACLE_CACHE``, else the user's cache directory (results are generated data, never
    the repository's)."""
    env = os.environ.get("RVS_ORACLE_CACHE")
    if env:
        return Path(env)
    return Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "rvs" / "oracle"


def mission_key(scene: str, seed: int, start: tuple[float, float], goal: tuple[float, float],
                body: VehicleBody, max_expansions: int = MAX_EXPANSIONS) -> str:
    """The cache key of one mission's verdict: everything it depends on."""
    fields = dataclasses.asdict(body) if dataclasses.is_dataclass(body) else {
        k: getattr(body, k) for k in VehicleBody.__annotations__}
    fields["wheels"] = np.asarray(body.wheels, float).round(6).tolist()
    text = json.dumps({"scene": scene, "seed": seed, "start": list(start), "goal": list(goal), "body": fields,
                       "budget": max_expansions, "weight": WEIGHT, "code": code_version()}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def mission_oracle(scene: str, seed: int, start: tuple[float, float], goal: tuple[float, float],
                   body: VehicleBody | None = None, cache_dir: Path | None = None,
                   max_expansions: int = MAX_EXPANSIONS) -> dict[str, Any]:
    """:func:`oracle` of one mission of ``scene`` (its truth surface and, by default, its body),
    read from the cache when it holds the same mission, body and code; else computed and stored
    (``cached``: whether it was read)."""
    from drivers.sim.world import World

    from .surface import truth_surface

    world = World.from_scene(scene) if body is None else None
    body = body if body is not None else world.body
    folder = cache_dir if cache_dir is not None else default_cache_dir()
    path = folder / f"{scene}_{mission_key(scene, seed, start, goal, body, max_expansions)}.json"
    if path.is_file():
        try:
            return {**json.loads(path.read_text()), "cached": True}
        except (OSError, ValueError):
            pass  # a torn or foreign file: computed again and overwritten
    world = world or World.from_scene(scene)
    out = oracle(truth_surface(world, scene), body, start, goal, max_expansions)
    out.update(scene=scene, seed=seed, start=list(start), goal=list(goal))
    folder.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps(out))
    tmp.replace(path)
    return {**out, "cached": False}
