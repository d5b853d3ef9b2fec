"""move-ptu, grab-tof, grab-stereo and the sim commands end to end, and device faults through
the server: each ends in E_DEVICE naming the device, the server keeps serving, reset recovers."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
import yaml

FAST = ["drivers.ptu.timeout=0.5", "drivers.ptu.move_timeout=1.0", "drivers.stereo.trigger_timeout=0.3",
        "drivers.tof.timeout=0.5", "grab_stereo.resolution=low"]


@pytest.fixture
def hw(server_factory):
    srv = server_factory(FAST)
    c = srv.client()
    c.srv = srv
    yield c
    c.close()


def test_move_ptu_moves_the_sensor_head_in_the_world(hw) -> None:
    r = hw.request("move-ptu -pan 30 -tilt -10")
    assert r.status == "OK"
    # 185.1428 arc-seconds per position: PP583 / TP-194 are the nearest positions
    assert float(r.fields["pan"]) == pytest.approx(583 * 185.1428 / 3600, abs=1e-3)
    assert float(r.fields["tilt"]) == pytest.approx(-194 * 185.1428 / 3600, abs=1e-3)
    truth = hw.request("sim truth")
    assert float(truth.fields["pan"]) == pytest.approx(float(r.fields["pan"]), abs=1e-3)
    assert float(truth.fields["tilt"]) == pytest.approx(float(r.fields["tilt"]), abs=1e-3)
    st = hw.request("status")
    assert st.fields["ptu"] == f"{float(r.fields['pan']):.3f},{float(r.fields['tilt']):.3f}"
    r = hw.request("move-ptu -tilt 5")  # pan kept
    assert float(r.fields["pan"]) == pytest.approx(583 * 185.1428 / 3600, abs=1e-3)


def test_move_ptu_arguments(hw) -> None:
    r = hw.request("move-ptu -pan 170")
    assert r.fields["code"] == "E_ARG" and "limits" in r.fields["message"]
    assert hw.request("move-ptu").status == "OK"  # no axis given: no move (tests/server/test_declared_rules.py)
    assert hw.request("move-ptu -pan east").fields["code"] == "E_ARG"
    assert hw.request("status").fields["mode"] == "ready"  # an argument error is no fault


def test_grab_tof_writes_image_preview_and_sidecar(hw) -> None:
    assert hw.request("move-ptu -pan 0 -tilt -30").status == "OK"
    r = hw.request("@g7 grab-tof -output TestImage -type z -integrate 4")
    assert r.status == "OK" and r.tag == "g7" and r.fields["file"] == "tof/TestImage_z.tif"
    data = hw.srv.data
    z = tifffile.imread(data / r.fields["file"])
    assert z.shape == (144, 176) and z.dtype == np.float32
    valid = z[np.isfinite(z)]
    assert valid.size > 0.5 * z.size and 0.3 < np.median(valid) < 6.0
    assert (data / "tof/TestImage_z.png").stat().st_size > 0
    side = yaml.safe_load((data / "tof/TestImage_z.yaml").read_text())
    assert side["made_by"] == "grab-tof" and side["parameters"]["integrate"] == 4
    assert side["ptu"]["tilt"] == pytest.approx(-30, abs=0.05)
    r = hw.request("grab-tof -type xyz")
    xyz = tifffile.imread(data / r.fields["file"])
    assert xyz.shape == (144, 176, 3)


def test_grab_tof_refuses_hostile_names(hw) -> None:
    for name in ("../etc/passwd", "/tmp/x", ".hidden", "a/b", "x" * 65, '"a b"'):
        r = hw.request(f"grab-tof -output {name}")
        assert r.fields["code"] == "E_ARG", name
        assert "-output must be a file stem" in r.fields["message"]
    assert not any(p.name.startswith("passwd") for p in hw.srv.data.rglob("*"))


def test_grab_stereo_pair(hw) -> None:
    r = hw.request("grab-stereo -output pair1 -format rgb8")
    assert r.status == "OK" and r.fields["left"] == "stereo/pair1_left.tif"
    left = tifffile.imread(hw.srv.data / r.fields["left"])
    right = tifffile.imread(hw.srv.data / r.fields["right"])
    assert left.shape == right.shape == (480, 640, 3) and left.dtype == np.uint8
    assert left.std() > 5 and not np.array_equal(left, right)  # two viewpoints
    assert hw.request("grab-stereo -format yuv422").fields["code"] == "E_ARG"


def test_sim_commands(hw) -> None:
    r = hw.request("sim move-rover -dx 1 -dy 0.5 -dyaw 90")
    assert (float(r.fields["x"]), float(r.fields["y"]), float(r.fields["heading"])) == pytest.approx((1, 0.5, 90))
    r = hw.request("sim move-rover -dx 2")  # forward is now +y
    assert (float(r.fields["x"]), float(r.fields["y"])) == pytest.approx((1, 2.5), abs=1e-6)
    assert hw.request("sim scene").fields["scene"] == "office"
    assert hw.request("sim scene quarry").fields["scene"] == "quarry"
    assert hw.request("sim scene nosuch").fields["code"] == "E_ARG"
    assert hw.request("sim dance").fields["code"] == "E_ARG"
    assert hw.request("sim fault -device ptu -kind unplug").fields["code"] == "E_ARG"


@pytest.mark.parametrize(
    ("device", "kind", "request_line"),
    [
        ("ptu", "silent", "move-ptu -pan 10"),
        ("ptu", "garbage", "move-ptu -pan 10"),
        ("ptu", "stall", "move-ptu -pan 10"),
        ("tof", "unplug", "grab-tof -integrate 3"),
        ("tof", "timeout", "grab-tof"),
        ("stereo", "no_trigger", "grab-stereo"),
        ("trigger", "busy", "grab-stereo"),
    ],
)
def test_device_faults_end_in_e_device_and_reset_recovers(hw, device: str, kind: str, request_line: str) -> None:
    assert hw.request(f"sim fault -device {device} -kind {kind}").status == "OK"
    r = hw.request(request_line)
    assert r.status == "ERROR" and r.fields["code"] == "E_DEVICE"
    assert r.fields["device"] == device and device in r.fields["message"]
    st = hw.request("status")
    assert st.fields["mode"] == "fault" and f"{device}:error" in st.fields["devices"]
    assert hw.request("grab-tof").fields["code"] == "E_STATE"
    assert hw.request("version").status == "OK"  # still serving
    hw.request(f"sim fault -device {device} -kind none")
    r = hw.request("reset")
    assert r.status == "OK" and r.fields["mode"] == "ready", r.fields
    assert "error" not in r.fields["devices"]
    assert hw.request(request_line).status == "OK"


def test_break_interrupts_a_slow_ptu_move(server_factory) -> None:
    srv = server_factory(["drivers.ptu.time_scale=1", "drivers.ptu.speed=200"])
    c, other = srv.client(), srv.client()
    c.send("move-ptu -pan 150")
    job = c.reply().fields["job"]
    r = other.request("break")
    assert r.fields["interrupted"] == job
    final = c.until_final(job=job)[-1]
    assert final.fields["code"] == "E_INTERRUPTED"
    assert other.request("status").fields["mode"] == "break"  # not fault: nothing failed
    assert other.request("continue").fields["mode"] == "ready"
