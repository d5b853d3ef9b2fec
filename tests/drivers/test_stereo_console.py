"""rvs-cam: every library function reachable from the prompt, errors printed, images written."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import tifffile
import yaml
from support.stereo_fakeworld import FakeWorld

from drivers.stereo import console
from drivers.stereo import dc1394_lib as dc


def run(*lines: str, extra: tuple[str, ...] = (), world: Any = None) -> tuple[int, str, str]:
    """rc, stdout (the results) and stderr (echoed lines, start-up output, warnings, errors)."""
    out, err = io.StringIO(), io.StringIO()
    argv = ["--backend", "sim", "--resolution", "low", *extra]
    for line in lines:
        argv += ["-c", line]
    rc = console.main(argv, world=world if world is not None else FakeWorld(), stdout=out, stderr=err)
    return rc, out.getvalue(), err.getvalue()


def test_every_library_function_has_a_command() -> None:
    wanted = [
        "init", "deinit", "reset", "reinit", "status", "check", "ids", "list", "set_ids", "swap_ids",
        "settings", "set", "load", "save", "mode", "calibration", "grab_stereo", "grab_stereo_direct",
        "grab_mono", "grab_mono_direct", "grab_left", "grab_right", "pulse", "fault", "quit",
    ]  # fmt: skip
    for name in wanted:
        method = getattr(console.CamShell, f"do_{name}")
        assert method.__doc__, name


def test_grabs_write_tiff_and_png(tmp_path: Path) -> None:
    rc, out, err = run(
        f"grab-stereo {tmp_path}/pair.tif",
        f"grab-stereo {tmp_path}/colour.png fmt=rgb8",
        f"grab-left {tmp_path}/left.tif res=medium",
        f"grab-mono-direct right {tmp_path}/r.png",
    )
    assert rc == 0, err
    left = tifffile.imread(tmp_path / "pair_left.tif")
    right = tifffile.imread(tmp_path / "pair_right.tif")
    assert left.shape == right.shape == (480, 640) and left.dtype == np.uint8
    colour = cv2.imread(str(tmp_path / "colour_left.png"), cv2.IMREAD_UNCHANGED)
    assert colour.shape == (480, 640, 3)
    assert tifffile.imread(tmp_path / "left.tif").shape == (768, 1024)
    assert cv2.imread(str(tmp_path / "r.png"), cv2.IMREAD_UNCHANGED).shape == (480, 640)
    assert f"left: {tmp_path}/pair_left.tif (480x640" in out


def test_images_go_under_the_data_directory_not_the_working_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    rc, out, err = run("grab-stereo", "grab-left rel.tif")  # default: the server's data directory, ./data
    assert rc == 0, err
    stereo = tmp_path / "data" / "stereo"
    pair = sorted(stereo.glob("stereo-*_left.tif"))
    assert len(pair) == 1 and pair[0].with_name(pair[0].name.replace("_left", "_right")).is_file()
    assert tifffile.imread(stereo / "rel.tif").shape == (480, 640)
    assert f"left: {pair[0]} (480x640" in out and f"left: {stereo / 'rel.tif'} (480x640" in out
    assert not list(tmp_path.glob("*.tif"))

    rc, out, err = run("grab-right sub/r.png", extra=("--data", "elsewhere"))
    assert rc == 0 and (tmp_path / "elsewhere/stereo/sub/r.png").is_file()
    assert f"right: {tmp_path}/elsewhere/stereo/sub/r.png (480x640" in out


def test_rgb_png_keeps_the_channel_order(tmp_path: Path) -> None:
    image = np.zeros((4, 4, 3), np.uint8)
    image[..., 0] = 200  # red
    console.save_image(tmp_path / "red.png", image)
    console.save_image(tmp_path / "red.tif", image)
    bgr = cv2.imread(str(tmp_path / "red.png"), cv2.IMREAD_UNCHANGED)
    assert bgr[0, 0].tolist() == [0, 0, 200]
    assert tifffile.imread(tmp_path / "red.tif")[0, 0].tolist() == [200, 0, 0]


def test_errors_are_printed_and_the_session_goes_on(tmp_path: Path) -> None:
    rc, out, err = run(
        "mode yuv422",
        "set left bogus=1",
        "set left shutter_us=100000000",
        "fault no_trigger",
        "grab-stereo",
        "fault none",
        f"grab-stereo {tmp_path}/ok.tif",
        "ids",
        extra=("--data", str(tmp_path)),
    )
    assert rc == 1
    assert "error: ValueError: invalid pixel format 'yuv422'; accepted: mono8, rgb8" in err
    assert "unknown camera setting(s) bogus" in err
    assert "camera setting: shutter_us is 100000000, out of range" in err
    assert "error: DeviceError: stereo: camera" in err and "missed its trigger" in err
    assert "error:" not in out  # one-shot: errors are not results
    assert (tmp_path / "ok_left.tif").exists()  # the session survived every error


def test_an_unknown_command_is_refused_before_anything_runs(tmp_path: Path) -> None:
    rc, out, err = run(f"grab-stereo {tmp_path}/no.tif", "frobnicate", extra=("--data", str(tmp_path)))
    assert rc == 2 and out == ""
    assert err == "rvs-cam: unknown command 'frobnicate'; 'help' lists commands\n"
    assert not list(tmp_path.iterdir())


def test_ids_settings_and_files(tmp_path: Path) -> None:
    rc, out, err = run(
        "ids",
        "swap-ids",
        "set right gain_db=6 white_balance=500,520",
        f"save {tmp_path}/s.yaml",
        "set right gain_db=0",
        f"load {tmp_path}/s.yaml",
        "settings right",
        "calibration",
        "status",
        "check",
        "pulse",
        "reinit",
        "reset",
        extra=("--left-id", "1", "--right-id", "0"),
    )
    assert rc == 0, err
    assert "left: 000a470112f20002" in out  # --left-id 1 took the second camera
    assert "left: 000a470112f20001" in out  # ...and swap-ids swapped it back
    assert "gain_db: 6.0" in out.split("settings right")[-1]
    assert "image_size:\n- 640\n- 480" in out
    assert "pulse 1" in out or "pulse 2" in out


def test_interactive_prompt_reads_commands() -> None:
    world = FakeWorld()
    from drivers import stereo

    cam = stereo.create({"backend": "sim", "resolution": "low"}, world)
    out = io.StringIO()
    shell = console.CamShell(cam, stdout=out)
    shell.stdin = io.StringIO("init\nids\nswap-ids\nquit\n")
    shell.use_rawinput = False
    shell.cmdloop()
    assert "left: 000a470112f20002" in out.getvalue()
    cam.close()


def test_real_backend_without_libdc1394_reports_and_exits_nonzero(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(dc.ctypes.util, "find_library", lambda name: None)
    out, err = io.StringIO(), io.StringIO()
    rc = console.main(
        ["--backend", "dc1394", "--library", "libdc1394-rvs-absent.so", "--trigger-device", "/dev/parport-rvs-absent", "-c", "status"],
        stdout=out, stderr=err,
    )
    notes = err.getvalue()
    assert rc == 1
    assert "libdc1394 not found" in notes and "apt install libdc1394-25" in notes
    assert "warning: trigger box unavailable" in notes and "no parallel port device /dev/parport-rvs-absent" in notes
    assert "open: false" in out.getvalue()  # status still answers


def test_one_shot_calibration_is_the_yaml_rvs_odometry_reads(tmp_path: Path) -> None:
    """``rvs-cam -c calibration > calib.yaml``: stdout is the calibration alone (no ids from
    start-up, no echoed command line), so rvs-odometry reads the file as it is."""
    from prox_workflows.algorithms.stereo import load_calibration
    from prox_workflows.cli import odometry

    world = FakeWorld()
    rc, out, err = run("calibration", world=world)
    assert rc == 0, err
    assert "rvs-cam> calibration" in err and "left: 000a470112f20001" in err  # the transcript is on stderr
    calib_file = tmp_path / "calib.yaml"
    calib_file.write_text(out)
    calib = load_calibration(yaml.safe_load(calib_file.read_text()))
    assert calib.image_size == (640, 480)
    rc, out, err = run(f"grab-stereo {tmp_path}/a.tif", world=world)
    assert rc == 0, err
    a_left, a_right = tmp_path / "a_left.tif", tmp_path / "a_right.tif"
    assert odometry.main([str(a_left), str(a_right), str(a_left), "--calib", str(calib_file), "-q"]) == 0


@pytest.mark.parametrize(("extra", "message"), [
    (("--scene", "nosuch"), "rvs-cam: no scene 'nosuch'; known scenes: "),
    (("--config", "{bad}"), "rvs-cam: {bad}: not valid YAML: "),
    (("--config", "{missing}"), "rvs-cam: config file {missing} not found"),
])
def test_bad_setup_is_one_error_line_and_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                extra: tuple[str, str], message: str) -> None:
    paths = {"bad": tmp_path / "bad.yaml", "missing": tmp_path / "missing.yaml"}
    paths["bad"].write_text("stereo: [1\n")
    argv = [e.format(**paths) for e in extra]
    assert console.main([*argv, "-c", "ids"]) == 2  # the real world: no test double
    captured = capsys.readouterr()
    assert captured.out == "" and "Traceback" not in captured.err
    assert captured.err.count("\n") == 1 and captured.err.startswith(message.format(**paths)), captured.err
