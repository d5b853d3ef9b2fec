"""rvs-tof: one-shot command lines, TIFF grabs, errors caught and printed."""

from __future__ import annotations

import io
import json

import cv2
import numpy as np
import pytest
import tifffile
import usb.core
from tof_rig import floor_world, open_camera

from drivers.tof import Tof, mesasr
from drivers.tof import constants as k
from drivers.tof.console import TofConsole, main

# Every public camera function and the console command that reaches it.
COMMANDS = {
    "open": "open",
    "close": "close",
    "status": "status",
    "check": "check",
    "reinit": "reinit",
    "reset": "reset",
    "query": "query",
    "serial": "query",
    "inject_fault": "fault",
    "get_settings": "settings",
    "set_settings": "threshold",
    "set_amplitude_threshold": "threshold",
    "set_modulation": "modulation",
    "set_max_distance": "maxdist",
    "set_integration": "integration",
    "set_integration_ms": "intms",
    "set_auto_exposure": "autoexp",
    "get_correction_modes": "modes",
    "set_correction_modes": "modes",
    "get_mode": "modes",
    "set_enhanced_xyz": "enhanced",
    "get_enhanced_xyz": "enhanced",
    "set_undistort": "undistort",
    "set_colour_range": "colourrange",
    "get_colour_range": "colourrange",
    "save_settings": "save",
    "load_settings": "load",
    "create_default_settings_file": "default",
    "grab": "grab",
    "grab_xyz": "xyz",
    "intrinsics": "intrinsics",
    "undistort": "grab",
    "fake_colour": "grab",
}


def test_every_public_function_has_a_command():
    # reconfigure is the server's config -set hook (drivers.yaml keys) and noise_amplitude what the
    # server's maps take the noise from: neither is an rvs-libtof function
    server_side = ("name", "backend", "settings_file", "reconfigure", "noise_amplitude")
    public = {n for n in dir(Tof) if not n.startswith("_") and n not in server_side}
    assert public <= set(COMMANDS), f"no console command for {sorted(public - set(COMMANDS))}"
    for command in set(COMMANDS.values()):
        assert hasattr(TofConsole, f"do_{command}")


def test_one_shot_grab_writes_a_tiff_and_a_preview(tmp_path, capsys):
    tif, png = tmp_path / "floor_z.tif", tmp_path / "floor_z.png"
    rc = main(["--backend", "sim", "-c", "ptu 0 -55", "-c", f"grab z {tif} -n 4 -c 0.2 --preview {png}"])
    out = capsys.readouterr().out
    assert rc == 0, out
    image = tifffile.imread(tif)
    assert image.shape == (k.HEIGHT, k.WIDTH) and image.dtype == np.float32
    assert 1.0 < float(np.nanmedian(image)) < 1.6  # the office floor below the tilted head
    preview = cv2.imread(str(png))
    assert preview.shape == (k.HEIGHT, k.WIDTH, 3)
    assert f"z -> {tif}" in out


def test_xyz_and_settings_commands(tmp_path, capsys):
    xyz_path, amp_path, settings = tmp_path / "v.tif", tmp_path / "a.tif", tmp_path / "s.yaml"
    rc = main(
        [
            "-c",
            f"ptu 0 -40; modulation 15; integration 55; modes median=on conv_gray=off; save {settings}",
            "-c",
            f"xyz {xyz_path} -n 2 --amplitude {amp_path}; integration 10; load {settings}; check",
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0, out
    xyz = tifffile.imread(xyz_path)
    assert xyz.shape == (k.HEIGHT, k.WIDTH, 3) and (xyz[..., 2] > 0).mean() > 0.9
    assert tifffile.imread(amp_path).shape == (k.HEIGHT, k.WIDTH)
    checked = json.loads(out[out.rindex("{") :])
    assert checked["integration"] == 55 and checked["modulation_mhz"] == 15.0
    assert "median=on" in out and "conv_gray=off" in out


def test_errors_are_printed_and_the_console_carries_on(capsys, tmp_path):
    tif = tmp_path / "d.tif"
    rc = main(["-c", "modulation 20; integration 999; fault unplug; status", "-c", f"fault none; reinit; grab distance {tif}"])
    out, err = capsys.readouterr()
    assert rc == 1
    assert "error: modulation frequency 20" in err  # one-shot: errors on stderr, results on stdout
    assert "error: integration register 999" in err
    assert '"fault": "unplug"' in out  # status still answers while unplugged
    assert "error:" not in out and "open:" not in out
    assert tif.exists()  # reinit recovered and the last grab worked


def test_arguments_a_command_refuses_stop_the_run_before_the_camera_opens(capsys, tmp_path):
    assert main(["-c", f"grab distance {tmp_path / 'a.tif'}; grab colour x.tif"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1, err
    assert err.startswith("rvs-tof: grab: argument type: invalid choice: 'colour'") and "usage: grab" in err
    assert not (tmp_path / "a.tif").exists()


def test_disconnect_is_reported_with_the_device_name():
    cam = open_camera(floor_world())
    out = io.StringIO()
    console = TofConsole(cam, stdout=out)
    console.onecmd("fault unplug")
    console.onecmd("grab distance /tmp/never.tif")
    assert "error: tof: SR4000 disconnected (USB)" in out.getvalue() and console.failed


def test_real_backend_without_libmesasr_still_offers_the_usb_query(monkeypatch, capsys):
    monkeypatch.setattr(mesasr.ctypes.util, "find_library", lambda name: None)
    monkeypatch.setattr(usb.core, "find", lambda **kw: iter(()))
    rc = main(["--backend", "mesasr", "--library", "/nonexistent/libmesasr.so", "-c", "usb"])
    out, err = capsys.readouterr()
    assert rc == 1
    assert "error: tof: libmesasr not found" in err and "libmesasr-dev" in err
    assert "no SR4000 (1ad2:0074/0075) on the USB bus" in out


def test_bad_options_exit_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--backend", "gige"])
    assert exc.value.code == 2
    assert main(["--serial", "zz", "-c", "status"]) == 2
    assert "not hex" in capsys.readouterr().err


def test_interactive_session_from_stdin(tmp_path):
    cam = open_camera(floor_world())
    out = io.StringIO()
    console = TofConsole(cam, stdout=out)
    console.use_rawinput = False
    console.stdin = io.StringIO(f"maxdist 7\nintms 5\ncolourrange distance 0 3\ngrab distance {tmp_path / 'd.tif'} --preview {tmp_path / 'd.png'} --grey\nquit\n")
    console.cmdloop(intro="")
    text = out.getvalue()
    assert "modulation 15 MHz" in text and "integration 47 = 5.0 ms" in text
    assert (tmp_path / "d.png").exists() and not console.failed


def test_a_grab_named_without_extension_goes_under_the_data_directory_as_tif(tmp_path, monkeypatch, capsys):
    """``rvs-tof -c "grab distance t1"`` writes DATA/tof/t1.tif (not an extension-less t1 in the
    working directory) and says where, as rvs-cam does under DATA/stereo."""
    monkeypatch.chdir(tmp_path)
    assert main(["-c", "grab distance t1 --preview t1"]) == 0  # default: the server's data directory, ./data
    out, err = capsys.readouterr()
    written = tmp_path / "data" / "tof" / "t1.tif"
    assert tifffile.imread(written).shape == (k.HEIGHT, k.WIDTH)
    assert (tmp_path / "data" / "tof" / "t1.png").is_file()
    assert out.splitlines()[0].startswith(f"distance -> {written}: ")
    assert not (tmp_path / "t1").exists() and "open:" in err  # start-up's open is a note, not a result
    assert main(["--data", "elsewhere", "-c", "xyz sub/v --amplitude sub/a", "-c", "grab z z.png"]) == 1
    out, err = capsys.readouterr()
    assert (tmp_path / "elsewhere" / "tof" / "sub" / "v.tif").is_file()
    assert (tmp_path / "elsewhere" / "tof" / "sub" / "a.tif").is_file()
    assert "z.png: grabs are float32 TIFFs, name it .tif" in err


@pytest.mark.parametrize(("argv", "message"), [
    (["--scene", "nosuch"], "rvs-tof: no scene 'nosuch'"),
    (["--config", "{bad}"], "rvs-tof: {bad}: not valid YAML: "),
    (["--config", "{wrong}"], "rvs-tof: "),
    (["--config", "{missing}"], "rvs-tof: {missing}: no such file"),
])
def test_bad_setup_is_one_error_line_and_exit_2(tmp_path, capsys, argv, message):
    paths = {"bad": tmp_path / "bad.yaml", "wrong": tmp_path / "wrong.yaml", "missing": tmp_path / "missing.yaml"}
    paths["bad"].write_text(": : :\n")
    paths["wrong"].write_text("tof: {backend: [1]}\n")
    assert main([*(a.format(**paths) for a in argv), "-c", "status"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "Traceback" not in err
    assert err.count("\n") == 1 and err.startswith(message.format(**paths)), err


@pytest.mark.parametrize(("line", "says"), [
    ("integration x", "error: whole numbers expected; usage: integration REG"),
    ("intms q", "error: numbers expected; usage: intms MS"),
    ("maxdist abc", "error: numbers expected; usage: maxdist METRES"),
    ("threshold 1.5", "error: whole numbers expected; usage: threshold N"),
    ("modulation y", "error: numbers expected; usage: modulation MHZ"),
    ("autoexp on 1 2 x 4", "error: whole numbers expected; usage: autoexp on|off [MIN MAX PERCENT DESIRED [ITERATIONS]]"),
    ("colourrange distance 1 x", "error: numbers expected; usage: colourrange TYPE LOW HIGH | colourrange TYPE auto"),
    ("fault timeout q", "error: whole numbers expected; usage: fault unplug|timeout|none [AFTER]"),
    ("ptu 1 inf", "error: finite numbers expected; usage: ptu PAN TILT"),
])
def test_a_word_that_is_not_a_number_answers_with_the_command_s_usage(capsys, line, says):
    assert main(["-c", f"{line}; integration 20"]) == 1
    out, err = capsys.readouterr()
    assert says in err and "convert" not in err and "literal" not in err, err
    assert "integration 20 = 2.3 ms" in out  # the console carried on
