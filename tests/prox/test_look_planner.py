"""Where the see loop points the mast (``prox_workflows.algorithms.looks``), as plain functions
on the head's calibration, the D46 PTU's limits and the ToF's field of view: the gaze while
driving, a look at one point, a fan of pans, the round look, the blind disc and the view the
PTU's reported limits give."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.ptu.protocol import D46_LIMITS, D46_RESOLUTION_ARCSEC, pos_to_deg
from drivers.sim.rover import RoverBody
from drivers.tof.constants import FOV_H_DEG, FOV_V_DEG
from prox_workflows.algorithms.bounds_map import BoundsMap
from prox_workflows.algorithms.looks import (
    View,
    blind_disc,
    blind_radius,
    gaze,
    look_at,
    look_pans,
    looked_from_here,
    round_look,
    standing_look,
)
from prox_workflows.algorithms.transforms import HeadCalibration

LOWEST = pos_to_deg(D46_LIMITS["tilt"][0], D46_RESOLUTION_ARCSEC)  # -46.65 deg
FAR = -35.0  # see_tilt's default
HEAD = HeadCalibration()  # the pan axis 0.10 m ahead of the centre, the tilt axis 1.26 m up
VIEW = View(FOV_H_DEG, FOV_V_DEG, LOWEST)


def test_the_view_the_ptus_limits_give_pans_no_farther_than_its_lesser_side() -> None:
    limits = {"pan": {"min_deg": -170.0, "max_deg": 158.9}, "tilt": {"min_deg": -46.6, "max_deg": 31.0}}
    view = View.of_ptu(limits, FOV_H_DEG, FOV_V_DEG)
    assert (view.fov_h, view.fov_v, view.lowest_tilt, view.pan_limit) == (43.6, 34.6, -46.6, 158.9)
    limits["pan"] = {"min_deg": -150.0, "max_deg": 158.9}
    assert View.of_ptu(limits, FOV_H_DEG, FOV_V_DEG).pan_limit == 150.0


def test_the_blind_disc_is_round_the_pan_axis_foot_with_the_lowest_tilts_reach() -> None:
    x, y, r = blind_disc((1.0, 2.0, 90.0), HEAD, VIEW)
    # heading north: the pan axis, 0.10 m ahead of the centre, stands 0.10 m north of it
    assert (x, y) == pytest.approx((1.0, 2.1), abs=1e-12)
    # 1.26 m up, the view's lower edge 17.3 deg below the lowest tilt (63.95 deg down): 0.616 m out
    assert r == pytest.approx(1.26 / math.tan(math.radians(17.3 + 46.6457)), abs=1e-4)
    assert r == pytest.approx(0.6160, abs=1e-4) and r == blind_radius(HEAD, VIEW)


def test_the_gaze_alternates_far_and_near_holding_each_three_frames() -> None:
    """Straight ahead, the PTU at see_tilt, a hold of 3: frames 1-2 hold the far aim, frame 3 turns
    to the near one at the lowest tilt, frames 4-5 hold it, frame 6 goes back to far; with a hold
    of 1 (navigate's default) every frame turns."""
    path = np.array([(5.0, 0.0)])
    at = (0.0, FAR)
    moves = []
    for frame in range(1, 8):
        aim = gaze(frame, (0.0, 0.0, 0.0), path, HEAD, at, (LOWEST, FAR), 3)
        moves.append(aim)
        at = aim or at
    assert moves == [None, None, (0.0, LOWEST), None, None, (0.0, FAR), None]
    at, moves = (0.0, FAR), []
    for frame in range(1, 5):
        aim = gaze(frame, (0.0, 0.0, 0.0), path, HEAD, at, (LOWEST, FAR), 1)
        moves.append(aim)
        at = aim or at
    assert moves == [(0.0, LOWEST), (0.0, FAR), (0.0, LOWEST), (0.0, FAR)]


def test_the_gaze_pans_along_the_path_within_sixty_degrees_and_only_past_the_slack() -> None:
    # the path turns north 0.5 m ahead: the far point (1.8 m along) is at 73 deg, past the 60 deg cap
    turning = np.array([(0.5, 0.0), (0.5, 3.0)])
    assert gaze(1, (0.0, 0.0, 0.0), turning, HEAD, (0.0, FAR), (LOWEST, FAR), 3) == (60.0, FAR)
    # from a rover heading north it lies at -22.6 deg: rounded to -25
    assert gaze(1, (0.0, 0.0, 90.0), turning, HEAD, (0.0, FAR), (LOWEST, FAR), 3) == (-25.0, FAR)
    # heading west the path lies behind-right (-115 deg): the pan is capped at -60
    assert gaze(1, (0.0, 0.0, 180.0), turning, HEAD, (0.0, FAR), (LOWEST, FAR), 3) == (-60.0, FAR)
    # a path 10 deg off the heading: within a hold the mast does not pan (10 < 15 deg), at the
    # hold's end it re-aims, its pan rounded to 5 deg steps (10.6 and 11.2 deg -> 10)
    bent = np.array([(3 * math.cos(math.radians(10.0)), 3 * math.sin(math.radians(10.0)))])
    assert gaze(1, (0.0, 0.0, 0.0), bent, HEAD, (0.0, FAR), (LOWEST, FAR), 3) is None
    assert gaze(3, (0.0, 0.0, 0.0), bent, HEAD, (0.0, FAR), (LOWEST, FAR), 3) == (10.0, LOWEST)
    # already there: no move
    assert gaze(3, (0.0, 0.0, 0.0), bent, HEAD, (10.0, LOWEST), (LOWEST, FAR), 3) is None


def test_a_look_at_a_point_tilts_to_it_between_the_lowest_tilt_and_see_tilt_and_pans_within_150() -> None:
    pose = (1.0, 2.0, 90.0)  # heading north
    # 2 m ahead: the point's own tilt (-33.6 deg) is above see_tilt, which the look keeps
    pan, tilt = look_at(pose, 1.0, 4.0, HEAD, LOWEST, FAR)
    assert pan == pytest.approx(0.0, abs=1e-9) and tilt == FAR
    # 0.5 m ahead (72 deg down): no lower than the PTU goes
    pan, tilt = look_at(pose, 1.0, 2.5, HEAD, LOWEST, FAR)
    assert pan == pytest.approx(0.0, abs=1e-9) and tilt == LOWEST
    # 2 m to the left (west): 92.9 deg, the pan axis being 0.10 m ahead of the centre
    pan, tilt = look_at(pose, -1.0, 2.0, HEAD, LOWEST, FAR)
    assert pan == pytest.approx(92.862, abs=1e-3) and tilt == FAR
    # straight behind: 180 deg, panned no farther than 150
    assert look_at(pose, 1.0, 0.0, HEAD, LOWEST, FAR) == (-150.0, FAR)


def test_a_look_from_about_where_the_last_was_taken_is_the_same_look() -> None:
    last = (1.0, 1.0, 355.0)
    assert not looked_from_here(None, last)
    assert looked_from_here(last, (1.2, 1.0, 5.0))  # 0.2 m, 10 deg across north
    assert not looked_from_here(last, (1.4, 1.0, 355.0))  # 0.4 m away
    assert not looked_from_here(last, (1.1, 1.0, 20.0))  # turned 25 deg


def test_a_fan_of_pans_stays_within_150_degrees() -> None:
    assert look_pans(100.0, 40.0) == [60.0, 100.0, 140.0]
    assert look_pans(130.0, 40.0) == [90.0, 130.0, 150.0]
    assert look_pans(-130.0, 40.0) == [-150.0, -130.0, -90.0]


def test_the_round_look_fans_about_its_bearing_and_skips_ground_the_bounds_map_judged() -> None:
    body = RoverBody()
    pose = (0.0, 0.0, 0.0)
    # toward 90 deg (left): the lowest tilt left to right, then see_tilt back, all on the left
    toward = round_look(pose, HEAD, VIEW, body, 1.0, FAR, 90.0)
    assert toward == [(19.8, LOWEST), (56.8, LOWEST), (93.9, LOWEST), (131.0, LOWEST), (168.0, LOWEST),
                      (147.1, FAR), (110.0, FAR), (73.0, FAR), (35.9, FAR)]
    assert toward == standing_look(pose, HEAD, VIEW, body.length, body.width, 1.0,
                                   bearings=np.arange(-60.0, 60.1, 15.0) + 90.0, far_tilt=FAR)
    # all round: ten pans at each tilt
    assert len(round_look(pose, HEAD, VIEW, body, 1.0, FAR)) == 20
    # the bounds map holding all of that ground within 2.5 cm (under half of the 8 cm clearance): no frame
    bounds = BoundsMap.around((0.0, 0.0), 4.0, 0.25)
    bounds.set_down((0.0, 0.0), 3.9, 0.0, sigma=0.005)
    lower, upper, _ = bounds.window(-3.0, -3.0, 3.0, 3.0)
    assert float(np.nanmax(upper - lower)) == pytest.approx(0.025)
    assert round_look(pose, HEAD, VIEW, body, 1.0, FAR, 90.0, bounds) == []
    # held only within 1 m: the frames for the ground past it are left
    part = BoundsMap.around((0.0, 0.0), 4.0, 0.25)
    part.set_down((0.0, 0.0), 1.0, 0.0, sigma=0.005)
    left = round_look(pose, HEAD, VIEW, body, 1.0, FAR, 90.0, part)
    assert 0 < len(left) < len(toward)
    # within 5 cm (the default set-down's 1 cm sigma): too wide to count as judged, every frame is taken
    wide = BoundsMap.around((0.0, 0.0), 4.0, 0.25)
    wide.set_down((0.0, 0.0), 3.9, 0.0)
    assert round_look(pose, HEAD, VIEW, body, 1.0, FAR, 90.0, wide) == toward
