"""A wheel beside a rock, on a known surface: the map's cells pooled from a 5 mm truth (each cell's
mean, its highest and lowest ground as the returns' rise and drop), judged by the chance check and
by the vehicle check on the truth itself. The rock's edge cell holds the ground the wheel stands on
and the rock beside it; its top, read as the ground all over the cell, lifts the wheel."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drivers.sim.rover import RoverBody
from prox_workflows.algorithms.chance import ChanceParams, chance_check, posterior
from prox_workflows.algorithms.vehicle import LIMITS, check_poses
from prox_workflows.grid import GridGeometry

BODY = RoverBody()
FINE = 0.005  # m: the truth
CELL = 0.025  # m: the map, as the see loop's
AT_ORIGIN = np.array([[0.0, 0.0, 0.0]])
BELLY = LIMITS.index("belly")


def beside_a_rock(gap: float) -> tuple[np.ndarray, GridGeometry, dict[str, np.ndarray], GridGeometry]:
    """Flat ground, a rock under the box 5 mm over the belly's clearance (the truth: unsafe), and
    an 8 cm rock along the left side ``gap`` beyond the left wheels' outer edge (y 0.29 m): the
    truth at 5 mm, and the map's statistics pooled from it on 2.5 cm cells."""
    g = GridGeometry.covering(-0.6, -0.6, 0.6, 0.6, CELL)
    f = int(round(CELL / FINE))
    tg = GridGeometry(FINE, g.xmin, g.ymax, g.width * f, g.height * f)
    xs, ys = tg.centers()
    X, Y = np.meshgrid(xs, ys)
    truth = np.zeros(tg.shape)
    truth[(np.abs(X) < 0.05) & (np.abs(Y) < 0.05)] = BODY.clearance + 0.005
    edge = BODY.track / 2 + BODY.wheel_width / 2 + gap
    truth[(Y >= edge) & (Y < edge + 0.1) & (np.abs(X) < 0.3)] = 0.08
    blocks = truth.reshape(g.height, f, g.width, f)
    mean, top, low = blocks.mean(axis=(1, 3)), blocks.max(axis=(1, 3)), blocks.min(axis=(1, 3))
    stats = {"mean": mean, "mean_var": np.full(mean.shape, 0.002**2), "rise": top - mean, "drop": mean - low,
             "shift": np.zeros(mean.shape), "ceiling": np.full(mean.shape, np.inf), "upper": top.copy(),
             "lower": low.copy()}
    return truth, tg, stats, g


def test_a_wheel_beside_a_rock_does_not_rest_on_the_rock_s_edge_cell() -> None:
    # 5 mm between the wheels and the rock: on the truth the wheels stand on the flat ground and
    # the box's rock stands 5 mm into the belly. One surface (within 0) reads the edge cell's top
    # (the rock's 8 cm) as the ground under the wheels' outer edge, lifts the left side and passes
    # the pose; the declared check rests each wheel under the top by the cell's relief (the pair),
    # stands it on the flat ground and refuses the pose on the belly
    truth, tg, stats, g = beside_a_rock(0.005)
    on_truth = check_poses(truth, tg, AT_ORIGIN, BODY)
    assert on_truth.unsafe.tolist() == [True]
    assert on_truth.excess[0, BELLY] == pytest.approx(0.005, abs=1e-3)
    declared = ChanceParams()
    one_surface = dataclasses.replace(declared, within=0.0)
    one = chance_check(posterior(stats, g, 2.5, one_surface), g, AT_ORIGIN, BODY, one_surface)
    assert one.safe.tolist() == [True]  # the miss: the wheels' plane read high
    assert one.nominal.excess[0, BELLY] < -0.02
    c = chance_check(posterior(stats, g, 2.5, declared), g, AT_ORIGIN, BODY, declared)
    assert c.safe.tolist() == [False] and not c.unknown[0]
    assert c.prob[0, BELLY] > 0.1
    assert c.nominal.excess[0, BELLY] == pytest.approx(0.005, abs=0.002)  # the truth's intrusion, to 2 mm


def test_a_wheel_clear_of_the_rock_s_edge_cell_passes() -> None:
    # the rock moved 4 cm further out, its edge cell no longer under the wheels' read, and the
    # box's rock gone: the pair keeps the pose the truth keeps
    truth, tg, stats, g = beside_a_rock(0.045)
    under = (np.abs(g.centers()[0])[None, :] < 0.06) & (np.abs(g.centers()[1])[:, None] < 0.06)
    for name in ("mean", "upper", "lower"):
        stats[name] = np.where(under, 0.0, stats[name])
    stats["rise"], stats["drop"] = np.where(under, 0.0, stats["rise"]), np.where(under, 0.0, stats["drop"])
    truth[np.abs(truth - (BODY.clearance + 0.005)) < 1e-9] = 0.0
    assert check_poses(truth, tg, AT_ORIGIN, BODY).unsafe.tolist() == [False]
    c = chance_check(posterior(stats, g, 2.5), g, AT_ORIGIN, BODY)
    assert c.safe.tolist() == [True]


def test_a_prior_s_cells_are_not_lowered_by_the_pair() -> None:
    # a wheel's contact where the rover stood (a prior: no frame bounded it, its ground within the
    # standing wheel's hang of the plane its attitude gives) is the shared field's error, not a
    # rock edge's relief: the pair leaves it at its top, and lowers the framed cell beside it
    truth, tg, stats, g = beside_a_rock(0.005)
    framed = np.ones(g.shape, bool)
    framed[:, : g.width // 2] = False  # the rear half: the prior's
    stats["framed"] = framed
    stats["rise"][:, : g.width // 2] = 0.0125
    stats["drop"][:, : g.width // 2] = 0.0125
    post = posterior(stats, g, 2.5, ChanceParams(within=1.0))
    assert post.span is not None
    assert post.span[~framed].max() == 0.0
    assert post.span[framed].max() > 0.07
