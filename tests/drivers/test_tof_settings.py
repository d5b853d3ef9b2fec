"""SR4000 settings: frequencies, integration register, settings files, serial numbers, config."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from tof_rig import floor_world, open_camera

import drivers.tof as tof
from drivers.base import DeviceError
from drivers.tof import constants as k
from drivers.tof.settings import TofSettings, load_settings

CONFIG = Path(__file__).resolve().parents[2] / "config" / "drivers.yaml"


def test_unambiguous_range_is_c_over_2f():
    assert k.unambiguous_range(30.0) == pytest.approx(4.9965, abs=1e-4)
    assert k.unambiguous_range(15.0) == pytest.approx(9.9931, abs=1e-4)
    assert k.unambiguous_range(29.0) == pytest.approx(5.1688, abs=1e-4)


@pytest.mark.parametrize("mhz", [29, 30, 31, 14.5, 15, 15.5])
def test_sr4000_frequencies_are_accepted(mhz):
    assert k.check_frequency(mhz) == float(mhz)


@pytest.mark.parametrize("mhz", [20, 40, 10, 30.5, 0, -30])
def test_other_frequencies_are_refused(mhz):
    with pytest.raises(ValueError, match="29, 30, 31, 14.5, 15, 15.5"):
        k.check_frequency(mhz)


def test_frequency_enum_values_match_libmesasr():
    assert k.SR4000_FREQUENCIES[30.0] == 1 and k.SR4000_FREQUENCIES[15.0] == 6
    assert k.SR4000_FREQUENCIES[29.0] == 8 and k.SR4000_FREQUENCIES[31.0] == 9
    assert k.SR4000_FREQUENCIES[14.5] == 10 and k.SR4000_FREQUENCIES[15.5] == 11


@pytest.mark.parametrize(
    ("metres", "mhz"),
    [(1.0, 30.0), (4.9, 30.0), (5.0, 30.0), (5.1, 29.0), (5.17, 29.0), (5.2, 15.0), (10.0, 15.0), (10.2, 14.5), (10.34, 14.5)],
)
def test_frequency_chosen_by_maximum_distance(metres, mhz):
    assert k.frequency_for_distance(metres) == mhz


@pytest.mark.parametrize("metres", [10.5, 20.0, 0.0, -1.0])
def test_unreachable_distances_are_refused(metres):
    with pytest.raises(ValueError):
        k.frequency_for_distance(metres)


def test_integration_register_conversion():
    assert k.integration_ms(0) == pytest.approx(0.3)
    assert k.integration_ms(30) == pytest.approx(3.3)
    assert k.integration_ms(255) == pytest.approx(25.8)
    assert k.integration_register(3.3) == 30
    assert k.integration_register(0.3) == 0
    assert k.integration_register(25.8) == 255
    assert k.integration_register(3.34) == 30 and k.integration_register(3.36) == 31
    for bad in (-1, 256, 2.5, True):
        with pytest.raises(ValueError):
            k.check_integration(bad)
    for bad in (0.2, 25.9):
        with pytest.raises(ValueError):
            k.integration_register(bad)


def test_device_setters_validate_and_reach_the_camera():
    cam = open_camera(floor_world())
    cam.set_modulation(15)
    assert cam.check()["modulation_mhz"] == 15.0 and cam.status()["modulation_mhz"] == 15.0
    with pytest.raises(ValueError):
        cam.set_modulation(20)
    assert cam.get_settings().modulation_mhz == 15.0  # a refused value leaves the old one
    assert cam.set_integration_ms(5.0) == 47
    assert cam.check()["integration"] == 47 and cam.status()["integration_ms"] == 5.0
    with pytest.raises(ValueError):
        cam.set_integration(256)
    with pytest.raises(ValueError):
        cam.set_amplitude_threshold(70000)
    assert cam.set_max_distance(7.5) == 15.0


def test_settings_save_load_round_trip(tmp_path):
    cam = open_camera(floor_world())
    cam.set_settings(amplitude_threshold=120, modulation_mhz=14.5, integration=77, auto_exposure=False)
    cam.set_correction_modes(median=True, denoise_anf=False)
    cam.set_enhanced_xyz(True)
    cam.set_colour_range(0.5, 4.0, "distance")
    path = cam.save_settings(tmp_path / "sr4000.yaml")
    saved = yaml.safe_load(path.read_text())
    assert saved["modulation_mhz"] == 14.5 and saved["integration"] == 77 and saved["corrections"]["median"] is True

    other = open_camera(floor_world())
    assert other.get_settings().integration == 30
    loaded = other.load_settings(path)
    assert loaded == cam.get_settings()
    assert other.get_settings() == cam.get_settings()
    assert other.check()["integration"] == 77 and other.check()["modulation_mhz"] == 14.5
    assert other.get_mode() & k.AcquireMode.AM_MEDIAN and other.get_mode() & k.AcquireMode.AM_SHORT_RANGE
    assert other.get_colour_range("distance") == [0.5, 4.0]


def test_default_settings_file_is_created_when_missing_and_loaded_at_open(tmp_path):
    path = tmp_path / "cfg" / "tof_defaults.yaml"
    cam = open_camera(floor_world(), settings_file=str(path), integration=44)
    assert path.exists()
    assert load_settings(path).integration == 44
    assert cam.get_settings().integration == 44

    # An edited default file wins over the config on the next open, and reinit returns to it.
    data = yaml.safe_load(path.read_text())
    data["integration"] = 99
    path.write_text(yaml.safe_dump(data))
    cam2 = open_camera(floor_world(), settings_file=str(path), integration=44)
    assert cam2.check()["integration"] == 99
    cam2.set_integration(10)
    cam2.reinit()
    assert cam2.check()["integration"] == 99

    # CreateDefaultSettingsFile writes the built-in (config) defaults.
    cam2.create_default_settings_file()
    assert load_settings(path).integration == 44


def test_a_broken_settings_file_fails_open_with_the_reason(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("integration: 999\n")
    cam = tof.create({"backend": "sim", "settings_file": str(path)}, floor_world())
    with pytest.raises(DeviceError, match=": integration is 999, out of range"):
        cam.open()
    with pytest.raises(ValueError, match="unknown ToF setting"):
        TofSettings.from_dict({"shutter": 1})


def test_no_settings_file_configured():
    cam = open_camera(floor_world())
    with pytest.raises(ValueError, match="settings_file"):
        cam.save_settings()


@pytest.mark.parametrize(
    ("text", "value"),
    [(0, 0), ("0", 0), ("0x4000002F", 0x4000002F), ("4000002F", 0x4000002F), ("00-00-40-00-00-2F", 0x4000002F), (1234, 1234)],
)
def test_serial_numbers_parse_as_printed_on_the_camera(text, value):
    assert tof.parse_serial(text) == value


def test_open_by_serial():
    world = floor_world()
    assert tof.create({"backend": "sim", "serial": "0x4000002F"}, world).open() is None
    cam = tof.create({"backend": "sim", "serial": "0x40000099"}, world)
    with pytest.raises(DeviceError, match="0x40000099") as err:
        cam.open()
    assert err.value.device == "tof"


def test_shipped_config_section_builds_a_working_camera():
    config = yaml.safe_load(CONFIG.read_text())["tof"]
    settings = TofSettings.from_config(config)
    assert settings.corrections == {"fix_pattern": True, "median": False, "denoise_anf": True, "conv_gray": True, "conf_map": True}
    cam = tof.create(config, floor_world())
    cam.open()
    assert cam.status()["correction_modes"] == ["fix_pattern", "denoise_anf", "conv_gray", "conf_map"]
    assert cam.grab("z", 2).shape == (k.HEIGHT, k.WIDTH)


def test_unknown_backend():
    with pytest.raises(DeviceError, match="unknown backend"):
        tof.create({"backend": "firewire"})
