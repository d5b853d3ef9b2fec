"""orient (visual odometry) through the server, against the simulator's truth (sim truth).

The rover is moved by ``sim move-rover`` (the server is not told); each orient must find the
motion from the images alone: per 1 m step the translation error stays under 2 % of the
distance moved and the heading error under 0.5 degrees.
"""

from __future__ import annotations

import math

import pytest
from support.marks import LONG, long_only, long_test

# a straight step and a turning one by default (the default run's 6 minutes); all four in the long suite (marsyard)
STEPS = [(1.0, 0.0, 0.0), (1.0, 0.0, 6.0), (1.0, 0.0, -8.0), (1.0, 0.0, 3.0)][:None if LONG else 2]


def _truth(c) -> tuple[float, float, float]:
    t = c.request("sim truth").fields
    return float(t["x"]), float(t["y"]), float(t["heading"])


def _true_motion(before: tuple[float, float, float], after: tuple[float, float, float]) -> tuple[float, float, float]:
    """The truth's motion in the rover frame it started from (dx forward, dy left, dyaw)."""
    h = math.radians(before[2])
    ex, ey = after[0] - before[0], after[1] - before[1]
    dyaw = (after[2] - before[2] + 180.0) % 360.0 - 180.0
    return math.cos(h) * ex + math.sin(h) * ey, -math.sin(h) * ex + math.cos(h) * ey, dyaw


def _f(r, key: str) -> float:
    return float(r.fields[key])


# marsyard in the long suite (the default run's 6 minutes); quarry asserts the same by default
@pytest.mark.parametrize("scene", ["quarry", pytest.param("marsyard", marks=long_only())])
def test_orient_follows_the_rover(server_factory, scene: str) -> None:
    srv = server_factory([f"server.scene={scene}"])
    srv.app.world.set_target_visible(False)  # the astronaut walks nowhere here, but keep it out
    c = srv.client(timeout=60)
    r = c.request("orient")
    assert r.status == "OK", r.fields
    assert r.fields["reference"] == "true" and _f(r, "dx") == 0.0 and int(r.fields["points"]) > 500
    assert (_f(r, "x"), _f(r, "y"), _f(r, "heading")) == (0.0, 0.0, 0.0)
    before = _truth(c)
    report = []
    for dx, dy, dyaw in STEPS:
        c.request(f"sim move-rover -dx {dx} -dy {dy} -dyaw {dyaw}")
        r = c.request("orient")
        assert r.status == "OK", r.fields
        after = _truth(c)
        tdx, tdy, tdyaw = _true_motion(before, after)
        dist = math.hypot(tdx, tdy)
        t_err = math.hypot(_f(r, "dx") - tdx, _f(r, "dy") - tdy)
        h_err = abs(_f(r, "dyaw") - tdyaw)
        report.append((round(100 * t_err / dist, 3), round(h_err, 3), r.fields["matches"], r.fields["inliers"]))
        assert t_err < 0.02 * dist, (scene, (dx, dy, dyaw), r.fields, (tdx, tdy, tdyaw))
        assert h_err < 0.5, (scene, (dx, dy, dyaw), r.fields, tdyaw)
        assert int(r.fields["inliers"]) >= 100 and int(r.fields["matches"]) >= int(r.fields["inliers"])
        # the server's pose follows (it is the pose of the last orient plus this motion)
        assert srv.app.pose.x == pytest.approx(_f(r, "x"), abs=1e-3)
        before = after
    print(f"\n{scene}: per step (translation error %, heading error deg, matches, inliers): {report}")
    x, y, heading = _truth(c)
    pose = srv.app.pose
    assert math.hypot(pose.x - x, pose.y - y) < 0.02 * len(STEPS)
    assert abs(pose.heading - heading) < 0.5 * len(STEPS)


@long_test  # the default run's time; orient on quarry runs there
def test_orient_without_overlap_is_e_data_and_keeps_pose(server_factory) -> None:
    srv = server_factory(["server.scene=quarry"])
    srv.app.world.set_target_visible(False)
    c = srv.client(timeout=60)
    assert c.request("orient").status == "OK"
    srv.app.set_pose(5.0, -2.0, 30.0)  # the GNC's word, which a failed orient must not touch
    c.request("sim move-rover -dyaw 150")
    r = c.request("orient")
    assert r.status == "ERROR" and r.fields["code"] == "E_DATA", r.fields
    msg = r.fields["message"]
    assert "matches=" in msg and "inliers=" in msg and "points=" in msg
    pose = srv.app.pose
    assert (pose.x, pose.y, pose.heading) == (5.0, -2.0, 30.0)
    # a different sensor needs a new reference
    r = c.request("orient -sensor tof")
    assert r.status == "ERROR" and r.fields["code"] == "E_ARG" and "-reset" in r.fields["message"]
    # -reset starts again from here, and the next step is measured from it
    r = c.request("orient -reset")
    assert r.status == "OK" and r.fields["reference"] == "true"
    c.request("sim move-rover -dx 1")
    r = c.request("orient")
    assert r.status == "OK", r.fields
    assert _f(r, "dx") == pytest.approx(1.0, abs=0.02) and abs(_f(r, "dyaw")) < 0.5
    # the motion is added to the pose the reference had (30 deg heading)
    assert _f(r, "x") == pytest.approx(5.0 + math.cos(math.radians(30)), abs=0.02)
    assert _f(r, "y") == pytest.approx(-2.0 + math.sin(math.radians(30)), abs=0.02)


def test_orient_with_tof_in_short_steps(server_factory) -> None:
    """The SR4000 sees 1-5 m and its own lighting moves with it: orient -sensor tof is for short
    steps (0.3 m here), where it holds about a centimetre and a few tenths of a degree."""
    srv = server_factory(["server.scene=quarry"])
    srv.app.world.set_target_visible(False)
    c = srv.client(timeout=60)
    assert c.request("orient -sensor tof").status == "OK"
    before = _truth(c)
    for dyaw in (0.0, 3.0, -3.0):
        c.request(f"sim move-rover -dx 0.3 -dyaw {dyaw}")
        r = c.request("orient -sensor tof")
        assert r.status == "OK", r.fields
        after = _truth(c)
        tdx, tdy, tdyaw = _true_motion(before, after)
        assert math.hypot(_f(r, "dx") - tdx, _f(r, "dy") - tdy) < 0.015, (r.fields, tdx, tdy)
        assert abs(_f(r, "dyaw") - tdyaw) < 0.5
        before = after
