"""The set-down's plane from the ring of seen ground round the mast's blind disc
(prox_workflows.algorithms.set_down)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from prox_workflows.algorithms.bounds_map import BoundsMap
from prox_workflows.algorithms.set_down import FLOOR, ring_plane, set_down


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


FOOT = (0.1, 0.0, 0.72)  # the mast's foot and its blind disc's radius, the rover at the origin facing +x
TURN = 0.35  # m: the disc the body turns in, as the see loop gives it (set_down widens it to the wheels' corners)
TURNED = 0.385 + 0.05  # m: that disc as set_down takes it (vehicle.reach of the rover and two cells)


def _ground(bounds: BoundsMap, z: Any, seen_from: float = 0.72) -> None:
    """Every centimetre of ground ``z(x, y)`` outside the blind disc round :data:`FOOT` as one
    frame's returns."""
    x, y = (a.ravel() for a in np.meshgrid(np.arange(-1.6, 1.6, 0.01) + 0.005, np.arange(-1.6, 1.6, 0.01) + 0.005))
    keep = np.hypot(x - FOOT[0], y - FOOT[1]) > seen_from
    bounds.fuse(np.column_stack([x[keep], y[keep], z(x[keep], y[keep])]), 0.003)


def _bumps(seed: int) -> Any:
    """Ground of rocks and hollows 10-25 cm across, up to 5 cm high or deep (a dense field's)."""
    rng = np.random.default_rng(seed)
    cx, cy = rng.uniform(-1.6, 1.6, 120), rng.uniform(-1.6, 1.6, 120)
    h, r = rng.uniform(-0.05, 0.05, 120), rng.uniform(0.05, 0.12, 120)

    def z(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        d2 = (np.asarray(x)[..., None] - cx) ** 2 + (np.asarray(y)[..., None] - cy) ** 2
        return (h * np.exp(-d2 / (2 * r * r))).sum(axis=-1)
    return z


def _disc(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The blind disc's unseen ground past the turn's and the wheels' (a cell's width clear of each)."""
    return (np.hypot(x - FOOT[0], y - FOOT[1]) <= FOOT[2] - 0.02) & (np.hypot(x, y) > TURNED + 0.02) & \
        ((np.abs(x) > 0.29) | (np.abs(y) > 0.33))


def _cells(bounds: BoundsMap, where: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The map's cells where ``where(x, y)`` holds: x, y, the top (mean + rise) and its sd."""
    g = bounds.geometry
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    on = where(X, Y) & np.isfinite(bounds.mean)
    return X[on], Y[on], (bounds.mean + bounds.rise)[on], np.sqrt(bounds.mean_var[on])


def test_a_dip_in_the_blind_disc_off_the_wheels_is_not_claimed_known_within_a_centimetre() -> None:
    """Rough ground round the rover (rocks and hollows up to 5 cm, as in dense rock) and a 5 cm
    dip in the blind disc ahead of the front-left wheel, where the rover drives next: the ring of
    seen ground is 1.5 cm and more off its plane, so the disc is taken on that plane within that
    spread, and the dip's deepest cells lie within 4 of its sigmas (the 1 cm prior put them 6 and
    more out), 98 % of the disc's within 3. Under
    smooth ground the same ring says no more than FLOOR (1 cm): a hollow wholly inside the disc
    leaves no trace in the ring."""
    from drivers.sim.rover import RoverBody

    rough, dip = _bumps(3), (0.6, 0.25, 0.1)

    def truth(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return rough(x, y) - 0.05 * (np.hypot(np.asarray(x) - dip[0], np.asarray(y) - dip[1]) < dip[2])

    bounds = BoundsMap.covering([[-1.7, -1.7], [1.7, 1.7]], 0.0)
    _ground(bounds, truth)
    said = set_down(bounds, (0.0, 0.0, 0.0), float(truth(0.0, 0.0)), RoverBody(), (0.0, 0.0, 0.05), FOOT, TURN,
                    0.1, 0.5)
    assert "off it by" in said, said
    x, y, top, sd = _cells(bounds, _disc)
    assert len(x) > 1200 and sd.max() > 0.015, sd.max()  # nearer known ground it is known better
    inside = np.hypot(x - dip[0], y - dip[1]) < dip[2] - 0.02
    assert inside.sum() > 20
    off = (top - truth(x, y)) / sd
    assert off[inside].max() < 4.0 and (top[inside] - truth(x[inside], y[inside])).max() > 0.04, off[inside].max()
    assert np.percentile(np.abs(off), 98) < 3.0
    smooth = BoundsMap.covering([[-1.7, -1.7], [1.7, 1.7]], 0.0)
    _ground(smooth, lambda x, y: 0.05 * np.asarray(x) + 0.002 * np.sin(20 * np.asarray(y)))
    set_down(smooth, (0.0, 0.0, 0.0), 0.0, RoverBody(), (0.0, 2.86, 0.05), FOOT, TURN, 0.1, 0.5)
    assert _cells(smooth, _disc)[3] == pytest.approx(FLOOR, abs=1e-4)


def test_the_wheels_at_the_start_are_known_to_a_few_millimetres_from_the_attitude() -> None:
    """The rover stands in a hollow 4 cm below the ring's plane (dense mission 0's start), its
    wheels on a plane rolled 3 deg: their ground is taken from the pose and the IMU's attitude
    (0.1 deg off, its sigma 0.1 deg), each wheel's top within 4 mm of the truth and known to
    4 mm, where the ring's plane put them 4 cm high; the blind disc beyond the turn stays the
    ring's, within its spread. Without an attitude (a GNC that sends none) the wheels stand on
    the datum tipped as the ring is, within 1 cm."""
    from drivers.sim.rover import RoverBody, resting_attitude

    body = RoverBody()
    roll = math.radians(3.0)

    def truth(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        # a flat-bottomed hollow 4 cm deep the rover stands in, its rim 0.4-0.7 m out
        hollow = -0.04 * np.clip((0.7 - np.hypot(x, y)) / 0.3, 0.0, 1.0)
        return math.tan(roll) * y + 0.04 + hollow

    pose = (0.0, 0.0, 0.0)
    r, p = resting_attitude(body, truth, pose)
    bounds = BoundsMap.covering([[-1.7, -1.7], [1.7, 1.7]], 0.0)
    _ground(bounds, truth)
    datum = float(truth(0.0, 0.0))
    set_down(bounds, pose, datum, body, (r + 0.1, p - 0.1, 0.1), FOOT, TURN, 0.1, 0.5)
    wheels = np.array([[0.145, 0.245], [0.145, -0.245], [-0.145, 0.245], [-0.145, -0.245]])
    for hx, hy in wheels:
        x, y, top, sd = _cells(bounds, lambda X, Y, hx=hx, hy=hy: (np.abs(X - hx) < 0.03) & (np.abs(Y - hy) < 0.03))
        assert len(x) and np.abs(top - truth(x, y)).max() < 0.004 and sd.max() < 0.004, (hx, hy, top - truth(x, y), sd)
    x, y, top, sd = _cells(bounds, _disc)
    assert sd.min() >= FLOOR - 1e-6  # the ring is a clean plane: the hollow's rim inside the disc shows in none of it
    no_imu = BoundsMap.covering([[-1.7, -1.7], [1.7, 1.7]], 0.0)
    _ground(no_imu, truth)
    set_down(no_imu, pose, datum, body, None, FOOT, TURN, 0.1, 0.5)
    x, y, top, sd = _cells(no_imu, lambda X, Y: (np.abs(X - 0.145) < 0.03) & (np.abs(Y - 0.245) < 0.03))
    assert np.abs(top - truth(x, y)).max() < 0.01 and sd.max() == pytest.approx(0.01, abs=1e-4)


def test_the_blind_disc_meets_the_seen_ground_and_the_turn_s_disc_without_a_step() -> None:
    """Seen ground rough about a plane 4 cm over the wheels' (the simulator's frames' datum lies
    -1 to +3 cm off the wheels' plane): the ring's plane alone meets the turn's disc in a 4 cm
    step, and the seen ground in steps of its own roughness, which the chance check's draws then
    push over the climb (marsyard mission 0's start: every section refused on a step the truth
    does not have). Conditioned on the ground known beside it, the disc's mean steps no more than
    1.5 cm between neighbouring cells anywhere (the wheels' own cells sit 1.25 cm under their
    plane), its sigma no more than its floor (1 cm, beside seen ground known to a millimetre), and
    far from known ground it keeps the ring's spread."""
    from drivers.sim.rover import RoverBody

    rough = _bumps(5)

    def truth(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return 0.04 + rough(x, y)

    bounds = BoundsMap.covering([[-1.7, -1.7], [1.7, 1.7]], 0.0)
    _ground(bounds, truth)
    set_down(bounds, (0.0, 0.0, 0.0), 0.0, RoverBody(), (0.0, 0.0, 0.05), FOOT, TURN, 0.1, 0.5)
    g = bounds.geometry
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    band = np.hypot(X - FOOT[0], Y - FOOT[1]) <= FOOT[2] + 0.1
    mean, sd = np.where(band, bounds.mean, np.nan), np.where(band, np.sqrt(bounds.mean_var), np.nan)
    steps = np.concatenate([np.abs(np.diff(mean, axis=a)).ravel() for a in (0, 1)])
    sd_steps = np.concatenate([np.abs(np.diff(sd, axis=a)).ravel() for a in (0, 1)])
    assert np.nanmax(steps) < 0.015, np.nanmax(steps)
    assert np.nanmax(sd_steps) <= FLOOR, np.nanmax(sd_steps)
    ring = ring_plane(bounds, FOOT[:2], FOOT[2] + 0.1, FOOT[2] + 0.5, (0.0, 0.0))
    assert ring.spread > 0.012 and np.nanmax(sd) > 0.8 * ring.spread


def test_the_ground_under_the_start_s_body_is_the_ring_s() -> None:
    """A 4 cm hollow under the rover's box between its wheels, on rough ground: the set-down takes
    it within the ring's spread conditioned on the wheels' contacts (the hollow's cells read 3 cm
    high, within 3.2 of their sigmas, which reach the ring's 1.5 cm), not on the wheels' plane
    within 1 cm, where they stood 3 and more sigmas out."""
    from drivers.sim.rover import RoverBody

    rough = _bumps(3)

    def truth(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return rough(x, y) - 0.04 * (np.hypot(np.asarray(x), np.asarray(y)) < 0.12)

    bounds = BoundsMap.covering([[-1.7, -1.7], [1.7, 1.7]], 0.0)
    _ground(bounds, truth)
    set_down(bounds, (0.0, 0.0, 30.0), float(rough(0.0, 0.0)), RoverBody(), (0.0, 0.0, 0.05), FOOT, TURN, 0.1, 0.5)
    x, y, top, sd = _cells(bounds, lambda X, Y: np.hypot(X, Y) < 0.1)
    assert len(x) > 40 and sd.max() > 0.014 and sd.min() > FLOOR, (sd.min(), sd.max())
    assert 0.02 < float(np.median(top - truth(x, y))) < 0.04 and ((top - truth(x, y)) / sd).max() < 3.2
