"""ground-align through the server: the simulated world's true sensor mount differs from the
server's head calibration; the ground plane must reveal by how much (a 2 degree
misalignment recovered within 0.2 degrees), and the correction must land in the calibration
every transform reads."""

from __future__ import annotations

import numpy as np
import pytest

from prox_workflows.algorithms.ground_plane import sensor_attitude
from prox_workflows.algorithms.transforms import R_BODY_FROM_OPTICAL, HeadCalibration, make_T, rpy


def misalign(world, sensors: tuple[str, ...], roll: float, pitch: float) -> None:
    """The true mounts turned by roll / pitch (deg) in the PTU's tilt frame, as the server's
    HeadCalibration writes a mount's rpy."""
    for s in sensors:
        T = world.head.mounts[s]
        world.head.mounts[s] = make_T(rpy(roll, pitch, 0.0) @ R_BODY_FROM_OPTICAL, T[:3, 3])


def stored_rpy(srv, sensor: str) -> list[float]:
    return [float(v) for v in srv.app.config.get("head").mounts[sensor]["rpy"]]


def _f(r, key: str) -> float:
    return float(r.fields[key])


@pytest.mark.parametrize("roll,pitch", [(0.0, 2.0), (2.0, 0.0), (-1.4142, 1.4142)])
def test_ground_align_recovers_a_tof_mount_misalignment(server_factory, roll: float, pitch: float) -> None:
    srv = server_factory(["server.scene=office"])
    world = srv.app.world
    world.set_target_visible(False)
    misalign(world, ("tof",), roll, pitch)
    c = srv.client(timeout=60)
    r = c.request("ground-align")
    assert r.status == "OK", r.fields
    got = stored_rpy(srv, "tof")
    assert got[0] == pytest.approx(roll, abs=0.2) and got[1] == pytest.approx(pitch, abs=0.2), (got, r.fields)
    print(f"\nmount truth roll={roll} pitch={pitch}: stored {got[0]:.3f} {got[1]:.3f}, reply {r.fields}")
    assert got[2] == 0.0
    # the reply: the sensor's attitude on the rover and its height, against the truth
    t_tilt, t_roll, _ = sensor_attitude(world.head.T_rover_from_sensor("tof", *world.ptu()))
    assert _f(r, "tilt") == pytest.approx(t_tilt, abs=0.2)
    assert _f(r, "roll") == pytest.approx(t_roll, abs=0.2)
    true_height = world.sensor_pose("tof")[2, 3] - world.rover_z()
    assert _f(r, "height") == pytest.approx(true_height, abs=0.01)
    assert _f(r, "residual") < 0.01 and int(r.fields["points"]) > 10000
    assert r.fields["mount_rpy"].split(",")[:2] == [f"{got[0]:.3f}", f"{got[1]:.3f}"]
    assert (srv.data / r.fields["file"]).is_file()
    # every transform now reads the corrected mount: it matches the true one
    head = HeadCalibration.from_dict(srv.app.config.get("head").as_dict())
    for pan, tilt in ((0.0, -40.0), (60.0, -20.0)):
        R_belief = head.T_rover_from_sensor("tof", pan, tilt)[:3, :3]
        R_true = world.head.T_rover_from_sensor("tof", pan, tilt)[:3, :3]
        angle = np.degrees(np.arccos(np.clip((np.trace(R_belief.T @ R_true) - 1) / 2, -1, 1)))
        assert angle < 0.2, (pan, tilt, angle)
    # measured again, nothing is left to correct
    r = c.request("ground-align -frames 2")
    assert r.status == "OK" and _f(r, "misalignment") < 0.2


def test_ground_align_with_stereo_corrects_both_cameras(server_factory) -> None:
    srv = server_factory(["server.scene=office"])
    world = srv.app.world
    world.set_target_visible(False)
    misalign(world, ("left", "right"), 1.2, -1.6)  # 2 degrees, in both axes
    c = srv.client(timeout=60)
    r = c.request("ground-align -sensor stereo -frames 2")
    assert r.status == "OK", r.fields
    for cam in ("left", "right"):
        got = stored_rpy(srv, cam)
        assert got[0] == pytest.approx(1.2, abs=0.2) and got[1] == pytest.approx(-1.6, abs=0.2), (cam, got)
    assert stored_rpy(srv, "tof") == [0.0, 0.0, 0.0]


def test_ground_align_measure_only_and_no_ground(server_factory) -> None:
    srv = server_factory(["server.scene=office"])
    misalign(srv.app.world, ("tof",), 0.0, 2.0)
    c = srv.client(timeout=60)
    r = c.request("ground-align -apply false -frames 1")
    assert r.status == "OK" and r.fields["applied"] == "false"
    assert _f(r, "d_tilt") == pytest.approx(-2.0, abs=0.2)  # 2 degrees more downward than believed
    assert stored_rpy(srv, "tof") == [0.0, 0.0, 0.0]
    r = c.request("ground-align -tilt 30 -frames 1")  # looking up: no ground within reach
    assert r.status == "ERROR" and r.fields["code"] == "E_DATA", r.fields
    assert stored_rpy(srv, "tof") == [0.0, 0.0, 0.0]
