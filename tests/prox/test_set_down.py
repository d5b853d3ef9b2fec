"""The set-down's plane from the ring of seen ground round the mast's blind disc
(prox_workflows.algorithms.set_down)."""

from __future__ import annotations

import math

import numpy as np

from prox_workflows.algorithms.bounds_map import BoundsMap
from prox_workflows.algorithms.set_down import ring_plane


def _slope_frame(bounds: BoundsMap, grade_deg: float, rock: bool) -> None:
    """Every centimetre of ground on a plane rising ``grade_deg`` toward +x (0 at the origin),
    outside a 0.7 m disc round the origin (the blind disc no frame shows), with a 20 cm rock at
    (0.95, 0.3) in the ring if ``rock``."""
    x, y = (a.ravel() for a in np.meshgrid(np.arange(-1.5, 1.5, 0.01) + 0.005, np.arange(-1.5, 1.5, 0.01) + 0.005))
    keep = np.hypot(x, y) > 0.7
    x, y = x[keep], y[keep]
    z = math.tan(math.radians(grade_deg)) * x
    if rock:
        z = z + np.where(np.hypot(x - 0.95, y - 0.3) < 0.12, 0.2, 0.0)
    bounds.fuse(np.column_stack([x, y, z]), 0.003)


def test_the_ring_round_the_blind_disc_gives_the_slope_the_rover_stands_on() -> None:
    """On a 12 deg slope the ring of seen ground gives the plane through the rover's foot within
    0.3 deg and 5 mm, a rock in the ring taken out of the fit; a level prior there would stand
    15 cm off the seen ground at the disc's edge downhill."""
    for rock in (False, True):
        bounds = BoundsMap.covering([[-1.6, -1.6], [1.6, 1.6]], 0.0)
        _slope_frame(bounds, 12.0, rock)
        ring = ring_plane(bounds, (0.0, 0.0), 0.8, 1.2, (0.0, 0.0))
        assert abs(math.degrees(math.atan(ring.gx)) - 12.0) < 0.3 and abs(ring.gy) < 0.005, (ring, rock)
        assert abs(ring.z0) < 0.005, ring.z0
        assert ring.said.startswith("the plane of"), ring.said


def test_with_too_little_seen_round_the_disc_it_is_level() -> None:
    bounds = BoundsMap.covering([[-1.6, -1.6], [1.6, 1.6]], 0.0)
    bounds.fuse(np.array([[0.9, 0.0, 0.1], [0.9, 0.001, 0.1]]), 0.003)  # one cell
    ring = ring_plane(bounds, (0.0, 0.0), 0.8, 1.2, (0.0, 0.0))
    assert (ring.z0, ring.gx, ring.gy) == (0.0, 0.0, 0.0) and ring.said.startswith("level ground"), ring.said
    assert not ring.known  # nothing said of the disc's ground: it stays unseen
