"""rvs-cam: every library function reachable from the prompt, errors printed, images written."""

from __future__ import annotations

import importlib.util
import io
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import tifffile

from drivers.stereo import console
from drivers.stereo import dc1394_lib as dc


def _load_fakeworld() -> Any:
    name = "rvs_tests_stereo_fakeworld"
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("stereo_fakeworld.py"))
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


FakeWorld = _load_fakeworld().FakeWorld


def run(*lines: str, extra: tuple[str, ...] = (), world: Any = None) -> tuple[int, str]:
    out = io.StringIO()
    argv = ["--backend", "sim", "--resolution", "low", *extra]
    for line in lines:
        argv += ["-c", line]
    rc = console.main(argv, world=world if world is not None else FakeWorld(), stdout=out)
    return rc, out.getvalue()


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
    rc, out = run(
        f"grab-stereo {tmp_path}/pair.tif",
        f"grab-stereo {tmp_path}/colour.png fmt=rgb8",
        f"grab-left {tmp_path}/left.tif res=medium",
        f"grab-mono-direct right {tmp_path}/r.png",
    )
    assert rc == 0, out
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
    rc, out = run("grab-stereo", "grab-left rel.tif")  # default: the server's data directory, ./data
    assert rc == 0, out
    stereo = tmp_path / "data" / "stereo"
    pair = sorted(stereo.glob("stereo-*_left.tif"))
    assert len(pair) == 1 and pair[0].with_name(pair[0].name.replace("_left", "_right")).is_file()
    assert tifffile.imread(stereo / "rel.tif").shape == (480, 640)
    assert f"left: {pair[0]} (480x640" in out and f"left: {stereo / 'rel.tif'} (480x640" in out
    assert not list(tmp_path.glob("*.tif"))

    rc, out = run("grab-right sub/r.png", extra=("--data", "elsewhere"))
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
    rc, out = run(
        "mode yuv422",
        "set left bogus=1",
        "set left shutter_us=100000000",
        "frobnicate",
        "fault no_trigger",
        "grab-stereo",
        "fault none",
        f"grab-stereo {tmp_path}/ok.tif",
        "ids",
        extra=("--data", str(tmp_path)),
    )
    assert rc == 1
    assert "error: ValueError: invalid pixel format 'yuv422'; accepted: mono8, rgb8" in out
    assert "unknown camera setting(s) bogus" in out
    assert "shutter_us must be in" in out
    assert "unknown command 'frobnicate'" in out
    assert "error: DeviceError: stereo: camera" in out and "missed its trigger" in out
    assert (tmp_path / "ok_left.tif").exists()  # the session survived every error


def test_ids_settings_and_files(tmp_path: Path) -> None:
    rc, out = run(
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
    assert rc == 0, out
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
    out = io.StringIO()
    rc = console.main(
        ["--backend", "dc1394", "--library", "libdc1394-rvs-absent.so", "--trigger-device", "/dev/parport-rvs-absent", "-c", "status"],
        stdout=out,
    )
    text = out.getvalue()
    assert rc == 1
    assert "libdc1394 not found" in text and "apt install libdc1394-25" in text
    assert "warning: trigger box unavailable" in text and "no parallel port device /dev/parport-rvs-absent" in text
    assert "open: false" in text  # status still answers
