"""Typed driver settings: the settings classes the device backends declare are the only
keys drivers.yaml, --config overlays, --set and config -set accept, and a run-time change of an
SR4000 camera setting reaches the next grab. Servers are real, on real sockets."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from drivers.registry import DEVICE_KINDS, registry
from rvs_params import ParamSpec
from rvs_server.main import build_config, main


def wire(value: Any) -> str:
    """A value as an operator types it after key= (what ParamSpec.parse reads back)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list | tuple):
        return ",".join(wire(v) for v in value)
    return str(value)


def every_setting(drivers: Any = None) -> list[tuple[str, str]]:
    """(drivers key, value) for every key a front end or backend declares, at its value in
    ``drivers`` (a DriversConfig; None: the declared defaults); a mapping-valued key gives one
    item per sub-key (what config -set can address)."""
    items: list[tuple[str, str]] = []
    for kind in DEVICE_KINDS:
        specs: dict[str, ParamSpec] = registry(kind).settings_class().specs()
        assert specs, kind
        values = vars(drivers)[kind].as_dict() if drivers is not None else {n: s.default for n, s in specs.items()}
        for name, spec in specs.items():
            if spec.kind == "dict":
                items += [(f"{kind}.{name}.{sub}", wire(v)) for sub, v in values[name].items()]
            else:
                items.append((f"{kind}.{name}", wire(values[name])))
    return items


def test_a_misspelled_driver_key_in_an_overlay_is_refused_at_start(tmp_path: Path, capsys) -> None:
    (tmp_path / "drivers.yaml").write_text("ptu: {baudrat: 19200}\n")
    assert main(["--config", str(tmp_path), "--port", "0", "--data", str(tmp_path / "data")]) == 2
    err = capsys.readouterr().err
    assert "'baudrat'" in err and "baudrate" in err and "move_timeout" in err and "time_scale" in err
    assert not (tmp_path / "data").exists()  # refused before anything started

    with pytest.raises(ValueError, match="'sim_hfov_degs'.*sim_hfov_deg"):
        build_config(None, ["drivers.stereo.sim_hfov_degs=60"])
    with pytest.raises(ValueError, match="registered|sim\\|serial"):
        build_config(None, ["drivers.ptu.backend=usb"])


def test_every_declared_driver_key_is_accepted_by_set_and_by_config_set(server_factory) -> None:
    items = every_setting()
    assert {"drivers.stereo.sim_hfov_deg", "drivers.tof.colour_range.z", "drivers.trigger.exclusive"} <= {
        f"drivers.{k}" for k, _ in items}
    store = build_config(None, [f"drivers.{key}={value}" for key, value in items])
    assert store.get("drivers").tof.sim_supersample == 2
    store = build_config(None, ["drivers.stereo.sim_hfov_deg=60", "drivers.ptu.baudrate=19200"])
    assert store.get("drivers").stereo.sim_hfov_deg == 60.0 and store.get("drivers").ptu.baudrate == 19200

    srv = server_factory()
    items = every_setting(srv.store.get("drivers"))
    c = srv.client()
    try:
        for start in range(0, len(items), 20):  # a few requests, each under the line limit
            sets = " ".join(f'-set "{key}={value}"' for key, value in items[start:start + 20])
            r = c.request(f"config -module drivers {sets}")
            assert r.status == "OK", r.fields
            assert r.fields["pending"] == "none"  # the values in force again: nothing to rebuild
        r = c.request("config -module drivers -set stereo.sim_hfov_deg=60")
        assert r.status == "OK" and r.fields["pending"] == "stereo.sim_hfov_deg"
        r = c.request("config -module drivers -set ptu.baudrat=19200")
        assert r.fields["code"] == "E_ARG" and "'baudrat'" in r.fields["message"] and "baudrate" in r.fields["message"]
        text = c.request("help config").fields["text"]
        for key, _ in items:
            assert key.split(".")[1] in text, key
    finally:
        c.close()


def _grab(c: Any, data: Path, name: str) -> dict[str, Any]:
    r = c.request(f"grab-tof -output {name} -type distance -integrate 1")
    assert r.status == "OK", r.fields
    return yaml.safe_load((data / r.fields["file"]).with_suffix(".yaml").read_text())["device"]


def test_a_run_time_change_of_each_sr4000_setting_reaches_the_next_grab(server_factory) -> None:
    specs = registry("tof").settings_class().specs()
    live = {name for name, spec in specs.items() if spec.live}
    # one change per live (camera) key; auto exposure in a second round, as it overrides integration
    first = {
        "modulation_mhz": ("15", lambda d: d["modulation_mhz"] == 15.0),
        "integration": ("60", lambda d: d["integration"] == 60),
        "amplitude_threshold": ("100", lambda d: d["amplitude_threshold"] == 100),
        "corrections": ("fix_pattern,conf_map", lambda d: set(d["correction_modes"]) == {"fix_pattern", "conf_map"}),
        "enhanced_xyz": ("true", lambda d: d["enhanced_xyz"] is True),
        "undistort": ("false", lambda d: d["undistort"] is False),
        "colour_range.distance": ("[0,5]", lambda d: "distance:0,5" in d["colour_range"]),
    }
    second = {
        "auto_exposure": ("true", lambda d: d["exposure_mode"] == "auto"),
        "auto_exposure_params.desired": ("80", lambda d: d["auto_exposure_params"][3] == 80),
        "auto_exposure_max_iterations": ("5", lambda d: d["auto_exposure_max_iterations"] == 5),
    }
    assert {key.split(".")[0] for key in first | second} == live
    srv = server_factory()
    c = srv.client()
    try:
        before = _grab(c, srv.data, "before")
        for changes in (first, second):
            assert not any(check(before) for _, check in changes.values())
            sets = " ".join(f'-set "tof.{key}={value}"' for key, (value, _) in changes.items())
            r = c.request(f"config -module drivers {sets}")
            assert r.status == "OK" and r.fields["pending"] == "none", r.fields  # taken by the open camera
            after = _grab(c, srv.data, f"after{len(changes)}")
            failed = [key for key, (_, check) in changes.items() if not check(after)]
            assert not failed, (failed, after)
    finally:
        c.close()


def test_drivers_yaml_holds_no_copy_of_a_declared_default() -> None:
    """Defaults live in the settings classes; drivers.yaml says only what this rover changes
    (and which backend each device uses)."""
    shipped = yaml.safe_load((Path(__file__).parents[2] / "config" / "drivers.yaml").read_text())
    assert set(shipped) == set(DEVICE_KINDS)
    for kind, section in shipped.items():
        specs = registry(kind).settings_class().specs()
        copies = [key for key, value in (section or {}).items() if key != "backend" and value == specs[key].default]
        assert not copies, f"drivers.yaml repeats the declared defaults of {kind}: {copies}"
