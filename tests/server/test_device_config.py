"""config -set on drivers reaches the devices: the ToF's camera settings at once,
every other key when its device is next re-initialised, and a grab's sidecar says what the camera
measured with. All through a real server on a real socket."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile
import yaml

from drivers.tof import constants as k

RANGE_30 = k.unambiguous_range(30.0)  # 4.997 m
RANGE_15 = k.unambiguous_range(15.0)  # 9.993 m


@pytest.fixture
def hw(server_factory):
    srv = server_factory(["drivers.tof.timeout=0.5", "drivers.stereo.trigger_timeout=0.3"])
    c = srv.client()
    c.srv = srv
    # Level, facing the front wall of the office 5.3-5.8 m away: beyond 30 MHz's range, within 15 MHz's.
    assert c.request("move-ptu -pan 0 -tilt 0").status == "OK"
    yield c
    c.close()


def grab(c, name: str) -> tuple[np.ndarray, dict]:
    r = c.request(f"grab-tof -output {name} -type distance -integrate 4")
    assert r.status == "OK", r.fields
    path: Path = c.srv.data / r.fields["file"]
    return tifffile.imread(path), yaml.safe_load(path.with_suffix(".yaml").read_text())


def assert_15_mhz(image: np.ndarray, side: dict, wrapped: np.ndarray) -> None:
    """The wall reads at its true 5.3-5.8 m, where 30 MHz wrapped it to 0.3-0.8 m."""
    valid = image[np.isfinite(image)]
    assert np.median(valid) > 5.2 and np.mean(valid > RANGE_30) > 0.85
    both = np.isfinite(image) & np.isfinite(wrapped) & (image > RANGE_30 + 0.1)
    assert both.mean() > 0.8
    assert np.median(np.abs(image[both] - (wrapped[both] + RANGE_30))) < 0.05
    assert side["device"]["modulation_mhz"] == 15.0
    assert side["device"]["range_max_m"] == pytest.approx(RANGE_15, abs=1e-3)


def test_modulation_set_at_run_time_is_used_at_once_and_after_reinit_and_reset(hw) -> None:
    wrapped, side = grab(hw, "at30")
    assert np.nanmax(wrapped) < RANGE_30 and np.nanmedian(wrapped) < 1.0
    assert set(side["device"]["correction_modes"]) == {"fix_pattern", "denoise_anf", "conv_gray", "conf_map"}
    assert side["device"]["undistort"] is True

    r = hw.request("config -module drivers -set tof.modulation_mhz=15")
    assert r.status == "OK" and r.fields["tof_modulation_mhz"] == "15"
    assert_15_mhz(*grab(hw, "now15"), wrapped)
    assert r.fields["pending"] == "none"

    assert hw.request("reinit").status == "OK"
    assert_15_mhz(*grab(hw, "reinit15"), wrapped)
    assert hw.request("reset").status == "OK"
    assert_15_mhz(*grab(hw, "reset15"), wrapped)
    assert side["device"]["modulation_mhz"] == 30.0

    assert hw.request("config -module drivers -set tof.modulation_mhz=30").fields["pending"] == "none"
    back, side = grab(hw, "back30")
    assert side["device"]["modulation_mhz"] == 30.0 and np.nanmax(back) < RANGE_30


def test_other_keys_wait_for_reinit_and_the_rebuilt_devices_keep_working(hw) -> None:
    r = hw.request("config -module drivers -set tof.integration=60 -set tof.timeout=1.5 -set trigger.pulse_us=200")
    assert r.status == "OK" and r.fields["pending"] == "tof.timeout,trigger.pulse_us"
    _, side = grab(hw, "int60")
    assert side["device"]["integration"] == 60 and side["device"]["integration_ms"] == pytest.approx(6.3)

    r = hw.request("reinit -device trigger")
    assert r.status == "OK" and "error" not in r.fields["devices"]
    assert hw.request("config -module drivers").fields["pending"] == "tof.timeout"
    # the stereo pair fires the rebuilt trigger box, not the closed one
    assert hw.request("grab-stereo -resolution low").status == "OK"

    assert hw.request("reinit -device tof").status == "OK"
    assert hw.request("config -module drivers").fields["pending"] == "none"
    _, side = grab(hw, "rebuilt")
    assert side["device"]["integration"] == 60 and side["device"]["modulation_mhz"] == 30.0


def test_a_value_the_camera_refuses_changes_nothing(hw, tmp_path: Path) -> None:
    r = hw.request("config -module drivers -set tof.integration=90 -set tof.modulation_mhz=17")
    assert r.fields["code"] == "E_ARG" and "17" in r.fields["message"] and "SR4000" in r.fields["message"]
    r = hw.request("config -module drivers")
    assert (r.fields["tof_modulation_mhz"], r.fields["tof_integration"]) == ("30", "30")
    # With a settings file the camera's settings live there: a config change would be lost at reinit.
    settings = tmp_path / "tof.yaml"
    r = hw.request(f'config -module drivers -set "tof.settings_file={settings}"')
    assert r.fields["pending"] == "tof.settings_file"
    r = hw.request("config -module drivers -set tof.modulation_mhz=15")
    assert r.fields["code"] == "E_ARG" and "settings_file" in r.fields["message"]
    _, side = grab(hw, "still30")
    assert side["device"]["modulation_mhz"] == 30.0
