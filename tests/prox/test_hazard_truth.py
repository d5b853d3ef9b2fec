"""Dem2Hazard on the simulated worlds' true DEMs: every rock taller than the step threshold is
flagged, and the plain floor is safe."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage
from support.marks import long_test

from drivers.sim.world import World
from prox_workflows.algorithms.dem2hazard import HazardParams, dem2hazard
from prox_workflows.grid import GridGeometry
from rvs_truth.ceiling import perception_ceiling

PARAMS = HazardParams()  # config/dem2hazard.yaml's defaults: step 0.15 m, slope 20 deg, window 0.3 m


@pytest.mark.parametrize(("scene", "bounds"), [("office", (-2.0, -2.5, 5.0, 2.5)),
                                                ("marsyard", (-5.0, -9.0, 13.0, 9.0))])
def test_every_rock_taller_than_the_step_threshold_is_flagged(scene: str, bounds) -> None:
    world = World.from_scene(scene)
    g = GridGeometry.covering(*bounds, 0.02)
    dem = world.true_dem(g.cell, g.bounds)
    hazard = dem2hazard(dem, g.cell, PARAMS)["hazard"]
    tall = [r for r in world.rocks() if r["height"] > PARAMS.step_max + 0.01
            and bounds[0] + 0.5 < r["x"] < bounds[2] - 0.5 and bounds[1] + 0.5 < r["y"] < bounds[3] - 0.5]
    assert tall, "the scene should hold rocks taller than the step threshold"
    missed = []
    for rock in tall:
        row, col = g.cell_of(np.array(rock["x"]), np.array(rock["y"]))
        k = max(1, int(min(rock["a"], rock["b"]) / g.cell / 2))
        if not (hazard[int(row) - k:int(row) + k + 1, int(col) - k:int(col) + k + 1] == 255).any():
            missed.append(rock)
    assert missed == [], f"{len(missed)} of {len(tall)} tall rocks not flagged"


def test_the_office_floor_is_safe() -> None:
    world = World.from_scene("office")
    g = GridGeometry.covering(-2.0, -2.5, 5.0, 2.5, 0.02)
    dem = world.true_dem(g.cell, g.bounds)
    bare = world.true_dem(g.cell, g.bounds, include_objects=False)
    hazard = dem2hazard(dem, g.cell, PARAMS)["hazard"]
    # the floor: flat, away from rocks, the sandbox and objects by more than half a window
    flat = np.isclose(bare, 0.0, atol=1e-4) & np.isclose(dem, bare)
    floor = ndimage.binary_erosion(flat, iterations=math.ceil(PARAMS.window / g.cell / 2) + 1)
    assert floor.sum() > 0.5 * floor.size
    safe = (hazard[floor] == 0).mean()
    assert safe >= 0.95, safe


@long_test  # ten plans on perfect maps of hirise, ~8 s of CPU: what the window step's margins give
def test_hirise_passages_leave_a_perfect_5cm_map_a_window_of_a_centimetre() -> None:
    """The dense scene is at the edge of closing: mission 1's way leads over a cell whose true
    step (the cell centre's samples) is 15.1 cm and whose cell-mean step is 13.9 cm. A perfect
    cell-mean map at the 15 cm limit drives the body over it; with a 1.5 cm margin it finds the
    long way round, clear of every true hazard; with 2.5 cm it finds none. A perfect map of the
    surface's 3 cm means, its step taken every centimetre, finds that way round at the limit
    itself (tools.bench.navigate --ceiling has all ten missions and the 1 cm surface)."""
    rows = perception_ceiling("hirise", 2, limits=(0.15, 0.135, 0.125), maps=("cell_mean", "mean_3cm"))
    got = {(r["map"], r["step_max"]): r for r in rows if r["mission"] == 1}
    assert got["cell_mean", 0.15]["reached"] and got["cell_mean", 0.15]["crossed_cells"] > 0
    assert got["cell_mean", 0.135]["reached"] and got["cell_mean", 0.135]["crossed_cells"] == 0
    assert 0.35 < got["cell_mean", 0.135]["efficiency"] < 0.5  # the detour the true maps also take (ideal 0.443)
    assert not got["cell_mean", 0.125]["reached"]
    assert got["mean_3cm", 0.15]["reached"] and got["mean_3cm", 0.15]["crossed_cells"] == 0
    assert 0.35 < got["mean_3cm", 0.15]["efficiency"] < 0.5
    assert not got["mean_3cm", 0.135]["reached"]
