"""A standing look (``looks.standing_look``): the PTU positions at the lowest tilt and at -35 deg
whose frames show all the ground the body covers over the next drive and the one after, from
the mast's blind disc out; rendered by the simulator from those positions, that ground is seen."""

from __future__ import annotations

import numpy as np

from drivers.ptu.protocol import D46_LIMITS, D46_RESOLUTION_ARCSEC, pos_to_deg
from drivers.sim.rover import RoverBody
from drivers.sim.world import World
from drivers.tof.constants import FOV_H_DEG, FOV_V_DEG, HEIGHT, WIDTH
from prox_workflows.algorithms.looks import View, blind_radius, drive_band, standing_look
from prox_workflows.algorithms.transforms import HeadCalibration
from prox_workflows.grid import GridGeometry

LOWEST = pos_to_deg(D46_LIMITS["tilt"][0], D46_RESOLUTION_ARCSEC)
VIEW = View(FOV_H_DEG, FOV_V_DEG, LOWEST)


def _seen_cells(world: World, positions: list[tuple[float, float]], g: GridGeometry) -> np.ndarray:
    """The cells of ``g`` the simulated ToF's rays meet the ground in, over the frames at
    ``positions``."""
    seen = np.zeros(g.shape, bool)
    for pan, tilt in positions:
        world.set_ptu(pan, tilt)
        view = world.render_sensor("tof", WIDTH, HEIGHT)
        keep = np.isfinite(view.range.reshape(-1)) & (view.object_id.reshape(-1) != 1)
        pts = view.points.reshape(-1, 3)[keep]
        r, c = g.cell_of(pts[:, 0], pts[:, 1])
        inside = g.inside(r, c)
        seen[r[inside], c[inside]] = True
    return seen


def test_the_standing_look_shows_the_next_drives_band_beyond_the_blind_disc() -> None:
    world = World.from_scene("quarry", seed=1)
    world.set_target_visible(False)
    pose = world.rover_pose()
    body, head = RoverBody(), HeadCalibration()
    positions = standing_look(pose, head, VIEW, body.length, body.width, distance=1.0)
    tilts = sorted({t for _, t in positions})
    assert tilts == [LOWEST, -35.0]
    for tilt in tilts:  # a fan of +-60 deg of drives takes 3-5 pans at each tilt
        assert 3 <= sum(t == tilt for _, t in positions) <= 5, positions
    band = drive_band(pose, body.length, body.width, 2.0, np.arange(-60.0, 61.0, 15.0))
    c, s = np.cos(np.radians(pose[2])), np.sin(np.radians(pose[2]))
    dx, dy = band[:, 0] - pose[0], band[:, 1] - pose[1]
    fx, fy = c * dx + s * dy, -s * dx + c * dy
    foot = np.hypot(fx - head.ptu_base[0], fy - head.ptu_base[1])
    # the ground a frame can show: past the blind disc (a cell's width off its edge, where rays graze),
    # not under the body as it stands
    need = (foot > blind_radius(head, VIEW) + 0.05) & ~((np.abs(fx) <= body.length / 2) & (np.abs(fy) <= body.width / 2))
    assert need.sum() > 1000
    g = GridGeometry.covering(pose[0] - 3.0, pose[1] - 3.0, pose[0] + 3.0, pose[1] + 3.0, 0.05)
    seen = _seen_cells(world, positions, g)
    r, col = g.cell_of(band[need, 0], band[need, 1])
    shown = seen[r, col]
    assert shown.mean() >= 0.99, f"{(~shown).sum()} of {len(shown)} band samples unseen"


def test_ground_the_map_has_judged_takes_no_frame() -> None:
    pose = (0.0, 0.0, 0.0)
    body, head = RoverBody(), HeadCalibration()
    every = standing_look(pose, head, VIEW, body.length, body.width)
    g = GridGeometry.covering(-4.0, -4.0, 4.0, 4.0, 0.05)
    xs, ys = g.centers()
    ahead = np.broadcast_to(xs[None, :] > 0.0, g.shape) & np.broadcast_to(ys[:, None] < 10.0, g.shape)
    left = np.broadcast_to(ys[:, None] > 0.0, g.shape) & ahead
    assert standing_look(pose, head, VIEW, body.length, body.width, judged=(ahead, g)) == []
    half = standing_look(pose, head, VIEW, body.length, body.width, judged=(left, g))
    assert 0 < len(half) < len(every)
    assert all(pan < 15.0 for pan, _ in half), half  # only the right-hand ground is left to show


def test_a_standing_look_begins_at_the_end_of_its_fan_nearer_the_mast() -> None:
    pose = (0.0, 0.0, 0.0)
    body, head = RoverBody(), HeadCalibration()
    plain = standing_look(pose, head, VIEW, body.length, body.width)
    first_row = [p for p in plain if p[1] == plain[0][1]]
    lo, hi = first_row[0][0], first_row[-1][0]
    assert lo < hi  # a fan of several pans at the lowest tilt, from the lowest pan
    assert standing_look(pose, head, VIEW, body.length, body.width, start_pan=lo - 30.0) == plain
    # the mast at the far end: the same positions, begun there, each tilt's row the other way
    flipped = standing_look(pose, head, VIEW, body.length, body.width, start_pan=hi + 10.0)
    assert sorted(flipped) == sorted(plain) and flipped[0] == (hi, plain[0][1])
    rows = [[p for p in seq if p[1] == t] for seq in (plain, flipped) for t in (plain[0][1], plain[-1][1])]
    assert rows[2] == rows[0][::-1] and rows[3] == rows[1][::-1]
    # still a serpentine: the second tilt begins at its end nearer where the first ended
    n = len(rows[2])
    assert abs(flipped[n][0] - flipped[n - 1][0]) < abs(flipped[-1][0] - flipped[n - 1][0])
