"""The ToF's noise model in the bounds map, against the simulated SR4000 (drivers.tof on a world):
each return's sigma falls with its own amplitude (as the camera's phase noise does), frames the
camera averages narrow it by sqrt(N), and a return's range error moves it along its ray only, so
a cell's bounds spread along the ray and not across it; the bounds still hold the true surface."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import drivers.tof as tof_device
from drivers.sim.world import World
from prox_workflows.algorithms.bounds_map import BoundsMap
from prox_workflows.algorithms.hazard_monitor import ground_pixels
from prox_workflows.algorithms.noise import tof_sigma, tof_spread
from prox_workflows.grid import GridGeometry

EDGE_JUMP = 0.02  # as the see loop drops a depth edge's mixed pixels


@pytest.fixture(scope="module")
def world() -> World:
    return World.from_scene("marsyard", seed=1)


def _camera(world: World, denoise: bool = True) -> Any:
    device = tof_device.create({"backend": "sim", "seed": 3, "time_scale": 0}, world)
    device.open()
    if not denoise:
        device.set_correction_modes(denoise_anf=False)
    return device


def _ranges(xyz: np.ndarray) -> np.ndarray:
    return np.where(xyz[..., 2] > 0, np.linalg.norm(xyz, axis=2), np.nan)


def test_each_returns_sigma_falls_with_its_own_amplitude(world: World) -> None:
    """Two frames at one pose differ pixel by pixel by the camera's noise: the model's sigma at
    each pixel's amplitude (the gray conversion undone) predicts that difference in dark and
    bright pixels alike, where a sigma from the range alone misses the dark pixels' by 3x."""
    device = _camera(world, denoise=False)  # the on-chip filter smooths the noise it is drawn with
    world.set_ptu(0.0, -35.0)
    a, amplitude = device.grab_xyz(1, 0.0)
    b, _ = device.grab_xyz(1, 0.0)
    ra, rb = _ranges(a), _ranges(b)
    ok = np.isfinite(ra) & np.isfinite(rb)
    raw, mhz = device.noise_amplitude(amplitude, ra)
    assert mhz == 30.0
    sigma = tof_sigma(ra[ok], raw[ok], frequency_mhz=mhz, range_coeff=0.0)  # the range term is common to both
    z = (ra - rb)[ok] / (np.sqrt(2.0) * sigma)
    dark, bright = raw[ok] < np.percentile(raw[ok], 33), raw[ok] > np.percentile(raw[ok], 67)
    assert np.median(sigma[bright]) < 0.3 * np.median(sigma[dark])
    for part in (dark, bright):
        assert 0.9 < np.std(z[part]) < 1.1
    from_range = (ra - rb)[ok] / (np.sqrt(2.0) * tof_sigma(ra[ok]))
    assert np.std(from_range[dark]) > 2.5


def _look(world: World, device: Any, frames: int, pans: tuple[float, ...] = (-20.0, 20.0)
          ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Frames of the simulated camera at tilt -35 (each the average of ``frames``) as the see loop
    keeps and weighs them: global points, the sensor's position, and their height, along-ray and
    across-ray sigmas."""
    out = []
    for pan in pans:
        world.set_ptu(pan, -35.0)
        T = np.asarray(world.sensor_pose("tof"), dtype=np.float64)
        xyz, amplitude = device.grab_xyz(frames, 0.0)
        keep = ground_pixels(xyz, 1, 4.5, amplitude, 0.1, EDGE_JUMP)
        cam = xyz[keep].astype(np.float64)
        pts = cam @ T[:3, :3].T + T[:3, 3]
        raw, mhz = device.noise_amplitude(amplitude[keep], np.linalg.norm(cam, axis=1))
        out.append((pts, T[:3, 3], *tof_spread(pts, T[:3, 3], raw, frames=frames, frequency_mhz=mhz)))
    return out


def _map(world: World, frames: list[Any], along_ray: bool = True) -> BoundsMap:
    x0, y0, _ = world.rover_pose()
    m = BoundsMap.covering([[x0 - 1.0, y0 - 3.0], [x0 + 4.0, y0 + 3.0]], 0.0)
    for pts, origin, sigma, along, across in frames:
        m.fuse(pts, sigma, origin, 4.5, along, "tof", across if along_ray else None)
    return m


def _true_top(world: World, g: GridGeometry) -> np.ndarray:
    fine = world.true_dem(0.005, (g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax))
    f = int(round(g.cell / 0.005))
    return fine[:g.height * f, :g.width * f].reshape(g.height, f, g.width, f).max(axis=(1, 3))


def test_averaging_n_frames_narrows_the_bounds_by_sqrt_n(world: World) -> None:
    """16 frames averaged by the camera scatter a quarter as much as one; the map told so draws
    its cells' sigma about that much narrower (the range term, calibration and scattering, is in
    every frame alike and stays), and its bounds still hold the true tops."""
    device = _camera(world)
    world.set_ptu(0.0, -35.0)
    one = [_ranges(device.grab_xyz(1, 0.0)[0]) for _ in range(2)]
    many = [_ranges(device.grab_xyz(16, 0.0)[0]) for _ in range(2)]
    ok = np.isfinite(one[0]) & np.isfinite(one[1]) & np.isfinite(many[0]) & np.isfinite(many[1])
    assert 3.6 < np.std((one[0] - one[1])[ok]) / np.std((many[0] - many[1])[ok]) < 4.4
    m1, m16 = _map(world, _look(world, device, 1)), _map(world, _look(world, device, 16))
    both = np.isfinite(m1.mean) & np.isfinite(m16.mean)
    assert both.sum() > 4000
    ratio = np.median(np.sqrt(m1.mean_var[both])) / np.median(np.sqrt(m16.mean_var[both]))
    assert 2.5 < ratio < 4.0
    width = np.median((m1.upper - m1.lower)[both]) / np.median((m16.upper - m16.lower)[both])
    assert width > 2.0
    top = _true_top(world, m16.geometry)
    for m in (m1, m16):
        seen = np.isfinite(m.mean)
        assert np.mean(top[seen] <= m.upper[seen]) >= 0.99


def test_a_bound_spread_along_the_ray_is_narrower_across_it_and_still_holds_the_surface(world: World) -> None:
    """The same frames fused twice: spread along each return's ray (an ellipse) and as a disc of
    the same along-ray error. The ellipse lies within the disc, so the upper bound is nowhere
    higher and on thousands of cells lower; it still holds the true top where the disc does."""
    frames = _look(world, _camera(world), 1)
    ray, disc = _map(world, frames), _map(world, frames, along_ray=False)
    seen = np.isfinite(ray.mean)
    assert np.all(ray.upper[seen] <= disc.upper[seen] + 1e-6)
    assert np.sum(ray.upper[seen] < disc.upper[seen] - 0.01) > 1000
    top = _true_top(world, ray.geometry)
    held_ray, held_disc = np.mean(top[seen] <= ray.upper[seen]), np.mean(top[seen] <= disc.upper[seen])
    assert held_ray >= 0.995
    assert held_ray >= held_disc - 0.002


def test_a_posts_returns_spread_along_their_ray_not_across_it() -> None:
    """Returns on a 30 cm post 2 m out along x amid level ground, seen from the origin with 4 cm
    of range error along the ray and 2 mm across it: the post's top spreads over the ground's
    cells 4 cells along x (the ray) and one across; told no direction, a disc of 4 cells."""
    g = GridGeometry(0.025, 0.0, 1.0, 160, 80)
    sensor = np.array([0.0, 0.0, 1.2])
    xs, ys = np.meshgrid(np.arange(1.5, 2.5, 0.0125) + 0.003, np.arange(-0.3, 0.3, 0.0125) + 0.003)
    ground = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    post = np.array([[2.0125, 0.0125, 0.3]] * 4)
    pts = np.vstack([ground[np.hypot(ground[:, 0] - 2.0125, ground[:, 1] - 0.0125) > 0.02], post])
    ray, disc = BoundsMap(g), BoundsMap(g)
    ray.fuse(pts, 0.001, sensor, None, 0.04, sigma_across=0.002)
    disc.fuse(pts, 0.001, sensor, None, 0.04)
    r, c = (int(v[0]) for v in g.cell_of(np.array([2.0125]), np.array([0.0125])))
    for m in (ray, disc):
        assert m.upper[r, c + 4] > 0.29 and m.upper[r, c - 4] > 0.29  # along the ray: 2.5 sigmas, 4 cells
        assert m.upper[r, c + 6] < 0.02  # past them the ground's own
    assert ray.upper[r - 1, c] > 0.29 and ray.upper[r + 1, c] > 0.29  # across: the cell's own flank
    assert ray.upper[r - 3, c] < 0.02 and ray.upper[r + 3, c] < 0.02
    assert disc.upper[r - 3, c] > 0.29 and disc.upper[r + 3, c] > 0.29
