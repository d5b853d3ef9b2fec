"""Spike removal (prox_workflows/algorithms/spikes.py): lone flying-pixel cells go, obstacles stay."""

from __future__ import annotations

import numpy as np
import pytest

from prox_workflows.algorithms.dem2hazard import dem2hazard
from prox_workflows.algorithms.holes import fill_holes
from prox_workflows.algorithms.spikes import find_spikes
from prox_workflows.grid import GridGeometry, Layers
from prox_workflows.steps.dem import remove_spikes_layers
from rvs_params.hazard import HAZARDOUS

CELL = 0.02


def ground(n: int = 80, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A gently tilted plane (2 degrees) with 4 mm noise, 1 cm sigma and 6 points per cell."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n] * CELL
    dem = 0.035 * x + 0.004 * rng.standard_normal((n, n))
    return dem, x, y, np.full((n, n), 1e-4), np.full((n, n), 6, np.int32)  # type: ignore[return-value]


def hazard_after(dem: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    z = dem if mask is None else np.where(mask, np.nan, dem)
    filled, _ = fill_holes(z, CELL, 0.06)
    return dem2hazard(filled, CELL)["hazard"]


def test_a_flying_pixel_spike_and_a_pit_no_longer_make_a_step_hazard_on_open_ground() -> None:
    """The marsyard case: one cell 10 cm up (2 points), one 0.16 m away 7 cm down (1 point):
    max - min over the 0.3 m window passes the 0.15 m step; the true ground has no hazard."""
    dem, _, _, var, count = ground()
    truth = dem.copy()
    dem[40, 40] += 0.10
    count[40, 40] = 2
    dem[40, 48] -= 0.07
    count[40, 48] = 1
    assert (hazard_after(dem) == HAZARDOUS).any()  # the defect
    assert not (hazard_after(truth) == HAZARDOUS).any()
    mask = find_spikes(dem, var, count)
    assert set(zip(*np.nonzero(mask), strict=True)) == {(40, 40), (40, 48)}
    assert not (hazard_after(dem, mask) == HAZARDOUS).any()


def test_rocks_taller_than_the_step_and_a_well_seen_post_are_kept() -> None:
    """No cell of a 0.16 m rock (0.3 m across, its cells seen with 1-2 points as at far range)
    is taken for a spike, nor a one-cell post that 20 points agree on; both stay hazards."""
    dem, x, y, var, count = ground()
    r2 = ((x - 0.5) / 0.15) ** 2 + ((y - 0.5) / 0.15) ** 2
    rock = r2 < 1
    dem[rock] += 0.16 * np.sqrt(1 - r2[rock])
    count[rock] = np.where((np.arange(rock.sum()) % 2) == 0, 1, 2)
    dem[20, 60] += 0.3
    count[20, 60] = 20
    mask = find_spikes(dem, var, count)
    assert not mask[rock].any() and not mask[20, 60]
    hz = hazard_after(dem, mask)
    assert (hz[rock] == HAZARDOUS).any() and hz[20, 60] == HAZARDOUS


def test_the_jump_scales_with_the_cells_sigma_and_lone_cells_are_not_judged() -> None:
    dem, _, _, var, count = ground()
    dem[30, 30] += 0.08
    count[30, 30] = 1
    var[30, 30] = 0.025**2  # 4 sigma = 0.10 m > the 8 cm jump: a noisy cell, not a contradiction
    assert not find_spikes(dem, var, count)[30, 30]
    sparse = np.full((9, 9), np.nan)
    sparse[4, 4], sparse[4, 5], sparse[5, 4] = 0.3, 0.0, 0.0  # two neighbours: too few to judge
    assert not find_spikes(sparse).any()
    with pytest.raises(ValueError):
        find_spikes(np.zeros(5))


def test_the_workflow_step_clears_the_cell_in_every_layer() -> None:
    dem, _, _, var, count = ground(20)
    dem[10, 10] += 0.2
    count[10, 10] = 1
    g = GridGeometry(CELL, 0.0, 20 * CELL, 20, 20)
    out = remove_spikes_layers(Layers(g, {"dem": dem.astype(np.float32), "variance": var.astype(np.float32),
                                          "count": count}))
    assert np.isnan(out["dem"][10, 10]) and np.isnan(out["variance"][10, 10]) and out["count"][10, 10] == 0
    assert out["spikes"].sum() == 1 and out.meta["spikes_removed"] == 1
    assert np.isfinite(out["dem"]).sum() == 399
