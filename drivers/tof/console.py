"""``rvs-tof``: the SR4000 console of seed 000 sect. 4.2.13, for either backend.

Every public function of the ToF interface has a prompt command; every error is caught and
printed, so a session survives an unplugged camera. The console opens one camera at start-up
(``--serial``, 0 = the first found) unless ``--no-open``. ``-c "grab z floor.tif -n 10"`` runs
lines one-shot (``;`` separates several); the exit status is 1 if any of them failed, 2 if the
console could not start (a bad option or config). One-shot, stdout holds only the commands'
results; what ``open`` says at start-up, warnings and errors go to stderr.

Images go under ``--data DIR/tof/`` (the server's data directory by default, as ``rvs-cam``'s go
under ``stereo/``): a relative FILE is taken there, an absolute one as it is, and a FILE without
the ``.tif`` extension gets it; each grab prints the absolute path it wrote.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import tifffile
import yaml

from drivers.console import (
    DEFAULT_CONFIG,
    SETUP_ERRORS,
    DeviceConsole,
    default_data_dir,
    load_section,
    numbers,
    one_line,
    run,
    split_words,
)
from rvs_params import assignments
from rvs_params.cli import ToolParser

from . import constants as k
from .backend import BACKENDS
from .device import Cancelled, Tof, parse_serial
from .query import find_cameras


class _ArgParser(argparse.ArgumentParser):
    """argparse for a prompt command: errors become ValueError instead of exiting."""

    def error(self, message: str) -> None:  # type: ignore[override]
        usage = " ".join(self.format_usage().split()).removeprefix("usage: ")  # one line, however wide
        raise ValueError(f"{message}; usage: {usage}")

    def exit(self, status: int = 0, message: str | None = None) -> None:  # type: ignore[override]
        raise ValueError(message or "bad arguments")


def _on_off(word: str) -> bool:
    w = word.strip().lower()
    if w in ("on", "true", "1", "yes"):
        return True
    if w in ("off", "false", "0", "no"):
        return False
    raise ValueError(f"expected on or off, got {word!r}")


def _stats(image: np.ndarray) -> str:
    finite = image[np.isfinite(image)]
    if image.ndim == 3:
        defined = ~(image == -1).all(axis=-1)
        return f"{image.shape[1]}x{image.shape[0]}x3, {defined.mean() * 100:.1f}% defined"
    if finite.size == 0:
        return f"{image.shape[1]}x{image.shape[0]}, nothing defined"
    return (
        f"{image.shape[1]}x{image.shape[0]}, {finite.size / image.size * 100:.1f}% defined, "
        f"min {finite.min():.4g}, mean {finite.mean():.4g}, max {finite.max():.4g}"
    )


class TofConsole(DeviceConsole):
    tool = "rvs-tof"
    offline = DeviceConsole.offline | {"usb"}
    intro = "rvs-tof: SR4000 console; 'help' lists the commands, 'quit' leaves."
    prompt = "tof> "
    # As before: file errors and cancelled grabs print their message alone, like device errors.
    plain_errors = (*DeviceConsole.plain_errors, OSError, Cancelled)

    def __init__(self, camera: Tof, world: Any = None, stdout: TextIO | None = None,
                 data_dir: str | Path | None = None) -> None:
        super().__init__(stdout)
        self.cam = camera
        self.world = world
        self.out_dir = Path(data_dir if data_dir is not None else default_data_dir()) / "tof"

    def _image_path(self, name: Path, suffixes: tuple[str, ...] = (".tif", ".tiff")) -> Path:
        """Where an image named on the command line goes: under DATA/tof unless absolute, with
        the format's extension, so a bare name never lands extension-less in the working directory."""
        path = name if name.is_absolute() else self.out_dir / name
        if path.suffix.lower() not in suffixes:
            if path.suffix.lower() in (".png", ".jpg", ".jpeg", ".bmp") and suffixes[0] != ".png":
                raise ValueError(f"{name}: grabs are float32 TIFFs, name it .tif (--preview FILE.png draws a picture)")
            path = path.with_name(path.name + suffixes[0])
        path.parent.mkdir(parents=True, exist_ok=True)
        return path.absolute()

    # -- camera maintenance --------------------------------------------------------------------
    def do_open(self, arg: str) -> None:
        """open: open the camera (serial from --serial) and apply the default settings."""
        self.cam.open()
        self.say(f"open: {self.cam.query()['device_string']}")

    def do_close(self, arg: str) -> None:
        """close: close the camera."""
        self.cam.close()
        self.say("closed")

    def do_reset(self, arg: str) -> None:
        """reset: re-activate the camera (close, reopen) and set the default settings."""
        self.cam.reset()
        self.say("reset done")

    def do_reinit(self, arg: str) -> None:
        """reinit: set the default settings again (reopens a camera lost to an error)."""
        self.cam.reinit()
        self.say("reinit done")

    def do_status(self, arg: str) -> None:
        """status: the status structure (busy, trigger mode, image type, exposure, frequency ...)."""
        self.dump(self.cam.status())

    def do_check(self, arg: str) -> None:
        """check: ask the camera for its serial number and integration time."""
        self.dump(self.cam.check())

    def do_query(self, arg: str) -> None:
        """query: serial number, vendor/product ids, manufacturer and product of the open camera."""
        self.dump(self.cam.query())

    def do_usb(self, arg: str) -> None:
        """usb: list the SR4000 cameras on the USB bus (pyusb; works without libmesasr)."""
        cams = find_cameras()
        if not cams:
            self.say("no SR4000 (1ad2:0074/0075) on the USB bus")
        for c in cams:
            self.say(json.dumps(c))

    # -- settings ------------------------------------------------------------------------------
    def do_settings(self, arg: str) -> None:
        """settings: all current settings."""
        self.say(yaml.safe_dump(self.cam.get_settings().to_dict(), sort_keys=False).rstrip())

    def do_threshold(self, arg: str) -> None:
        """threshold N: amplitude threshold 0..65535 (distances below it read 0)."""
        (n,) = numbers(arg, 1, 1, "threshold N", int)
        self.cam.set_amplitude_threshold(n)
        self.say(f"amplitude threshold {n}")

    def do_modulation(self, arg: str) -> None:
        """modulation MHZ: 29, 30, 31, 14.5, 15 or 15.5 MHz."""
        (f,) = numbers(arg, 1, 1, "modulation MHZ")
        self.cam.set_modulation(f)
        self.say(f"modulation {f:g} MHz: unambiguous range {k.unambiguous_range(f):.3f} m")

    def do_maxdist(self, arg: str) -> None:
        """maxdist METRES: choose the modulation frequency that measures up to this distance."""
        (d,) = numbers(arg, 1, 1, "maxdist METRES")
        f = self.cam.set_max_distance(d)
        self.say(f"modulation {f:g} MHz: unambiguous range {k.unambiguous_range(f):.3f} m")

    def do_integration(self, arg: str) -> None:
        """integration REG: integration register 0..255 (0.3 ms + 0.1 ms per step)."""
        (n,) = numbers(arg, 1, 1, "integration REG", int)
        self.cam.set_integration(n)
        self.say(f"integration {n} = {k.integration_ms(n):.1f} ms")

    def do_intms(self, arg: str) -> None:
        """intms MS: integration time in ms (0.3 .. 25.8), rounded to a register step."""
        (ms,) = numbers(arg, 1, 1, "intms MS")
        reg = self.cam.set_integration_ms(ms)
        self.say(f"integration {reg} = {k.integration_ms(reg):.1f} ms")

    def do_autoexp(self, arg: str) -> None:
        """autoexp on|off [MIN MAX PERCENT DESIRED [ITERATIONS]]: auto exposure and its settling cap."""
        usage = "autoexp on|off [MIN MAX PERCENT DESIRED [ITERATIONS]]"
        words = split_words(arg, 1, 6, usage)
        nums = numbers(" ".join(words[1:]), 0, 5, usage, int)
        if len(nums) not in (0, 4, 5):
            raise ValueError("usage: autoexp on|off [MIN MAX PERCENT DESIRED [ITERATIONS]]")
        params = dict(zip(("min_integration", "max_integration", "percent_over", "desired", "max_iterations"), nums, strict=False))
        self.cam.set_auto_exposure(_on_off(words[0]), **params)
        s = self.cam.get_settings()
        self.say(f"auto exposure {'on' if s.auto_exposure else 'off'}: {s.auto_exposure_params}, cap {s.auto_exposure_max_iterations} frames")

    def do_modes(self, arg: str) -> None:
        """modes [NAME=on|off ...]: image correction modes (fix_pattern median denoise_anf conv_gray conf_map)."""
        words = assignments(shlex.split(arg), flag="modes", form="NAME=on|off ...")
        changes = {name: _on_off(value) for name, value in words.items()}
        modes = self.cam.set_correction_modes(**changes) if changes else self.cam.get_correction_modes()
        self.say(" ".join(f"{n}={'on' if v else 'off'}" for n, v in modes.items()) + f"  (mode 0x{self.cam.get_mode():04x})")

    def do_enhanced(self, arg: str) -> None:
        """enhanced on|off: enhanced XYZ (precise coordinates below 1 m)."""
        if arg.strip():
            self.cam.set_enhanced_xyz(_on_off(arg))
        self.say(f"enhanced xyz {'on' if self.cam.get_enhanced_xyz() else 'off'}")

    def do_undistort(self, arg: str) -> None:
        """undistort on|off: undistort 2-D grabs."""
        self.cam.set_undistort(_on_off(arg))
        self.say(f"undistort {arg.strip()}")

    def do_colourrange(self, arg: str) -> None:
        """colourrange TYPE LOW HIGH | colourrange TYPE auto: colour range for fake colouring."""
        words = split_words(arg, 2, 3, "colourrange TYPE LOW HIGH | colourrange TYPE auto")
        if len(words) == 2:
            if words[1] != "auto":
                raise ValueError("usage: colourrange TYPE LOW HIGH | colourrange TYPE auto")
            self.cam.set_colour_range(None, None, words[0])
        else:
            low, high = numbers(" ".join(words[1:]), 2, 2, "colourrange TYPE LOW HIGH | colourrange TYPE auto")
            self.cam.set_colour_range(low, high, words[0])
        self.say(f"colour range {words[0]}: {self.cam.get_colour_range(words[0]) or 'auto'}")

    do_colorrange = do_colourrange

    def do_load(self, arg: str) -> None:
        """load [PATH]: load settings (default: the configured settings file) into the camera."""
        self.cam.load_settings(arg.strip() or None)
        self.say("settings loaded")

    def do_save(self, arg: str) -> None:
        """save [PATH]: save the current settings (default: the configured settings file)."""
        self.say(f"settings saved to {self.cam.save_settings(arg.strip() or None)}")

    def do_default(self, arg: str) -> None:
        """default [PATH]: create a settings file with the built-in defaults."""
        self.say(f"default settings written to {self.cam.create_default_settings_file(arg.strip() or None)}")

    # -- images --------------------------------------------------------------------------------
    def check_grab(self, arg: str) -> argparse.Namespace:
        """grab's arguments, checked (ValueError) before a one-shot run touches the camera."""
        p = _ArgParser(prog="grab", add_help=False)
        p.add_argument("type", choices=k.IMAGE_TYPES)
        p.add_argument("file", type=Path)
        p.add_argument("-n", "--integrate", type=int, default=1)
        p.add_argument("-c", "--confidence", type=float, default=0.0)
        p.add_argument("--raw", action="store_true")
        p.add_argument("--preview", type=Path)
        p.add_argument("--grey", action="store_true")
        a = p.parse_args(shlex.split(arg))
        if a.preview is not None and a.type == "xyz":
            raise ValueError("previews are for 2-D images, not xyz")
        return a

    def check_xyz(self, arg: str) -> argparse.Namespace:
        """xyz's arguments, checked as grab's are."""
        p = _ArgParser(prog="xyz", add_help=False)
        p.add_argument("file", type=Path)
        p.add_argument("-n", "--integrate", type=int, default=1)
        p.add_argument("-c", "--confidence", type=float, default=0.0)
        p.add_argument("--amplitude", type=Path)
        return p.parse_args(shlex.split(arg))

    def do_grab(self, arg: str) -> None:
        """grab TYPE FILE.tif [-n N] [-c CONF] [--raw] [--preview FILE.png] [--grey]
        TYPE: distance amplitude confidence z xyz. Saves a float32 TIFF (FILE relative to DATA/tof,
        .tif added if missing); --raw skips undistortion."""
        a = self.check_grab(arg)
        file = self._image_path(a.file)
        preview = self._image_path(a.preview, (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")) if a.preview else None
        image = self.cam.grab(a.type, a.integrate, a.confidence, undistort=False if a.raw else None)
        tifffile.imwrite(file, image, photometric="rgb" if image.ndim == 3 else "minisblack",
                         metadata={"type": a.type, "integrate": a.integrate, "confidence": a.confidence})
        self.say(f"{a.type} -> {file}: {_stats(image)}")
        if preview is not None:
            import cv2

            colour = self.cam.fake_colour(image, a.type, mode="grey" if a.grey else "jet")
            if not cv2.imwrite(str(preview), colour):
                raise OSError(f"could not write {preview}")
            self.say(f"preview -> {preview}")

    def do_xyz(self, arg: str) -> None:
        """xyz FILE.tif [-n N] [-c CONF] [--amplitude FILE.tif]: XYZ image (m, -1 undefined), under DATA/tof."""
        a = self.check_xyz(arg)
        file = self._image_path(a.file)
        amplitude_file = self._image_path(a.amplitude) if a.amplitude is not None else None
        xyz, amplitude = self.cam.grab_xyz(a.integrate, a.confidence)
        tifffile.imwrite(file, xyz, photometric="rgb")
        self.say(f"xyz -> {file}: {_stats(xyz)}")
        if amplitude_file is not None:
            tifffile.imwrite(amplitude_file, amplitude)
            self.say(f"amplitude -> {amplitude_file}: {_stats(amplitude)}")

    def do_intrinsics(self, arg: str) -> None:
        """intrinsics: camera matrix and distortion used for undistortion."""
        K, dist = self.cam.intrinsics()
        self.dump({"camera_matrix": K.round(4).tolist(), "distortion": dist.tolist()})

    # -- simulation ----------------------------------------------------------------------------
    def do_fault(self, arg: str) -> None:
        """fault KIND [AFTER]: sim only; unplug, timeout or none, optionally after AFTER frames."""
        words = split_words(arg, 1, 2, "fault unplug|timeout|none [AFTER]")
        kind = None if words[0] == "none" else words[0]
        self.cam.inject_fault(kind, *numbers(" ".join(words[1:]), 0, 1, "fault unplug|timeout|none [AFTER]", int))
        self.say(f"fault {words[0]}")

    def do_ptu(self, arg: str) -> None:
        """ptu PAN TILT: sim only; point the simulated sensor head (degrees)."""
        pan, tilt = numbers(arg, 2, 2, "ptu PAN TILT")
        if self.world is None:
            raise ValueError("ptu needs the simulated world (--backend sim)")
        self.world.set_ptu(pan, tilt)
        self.say(f"head at pan {pan:g} tilt {tilt:g}")


def main(argv: list[str] | None = None) -> int:
    parser = ToolParser(prog="rvs-tof", description="SR4000 time-of-flight camera console (sim or mesasr)")
    parser.add_argument("--backend", choices=BACKENDS.names(), help="default: drivers.yaml tof.backend")
    parser.add_argument("--serial", help="camera serial (hex, as printed on the camera); 0 = first found")
    parser.add_argument("--library", help="mesasr: path of libmesasr.so")
    parser.add_argument("--settings", type=Path, help="default settings file (created when missing)")
    parser.add_argument("--scene", default="office", help="sim: scene of the simulated world")
    parser.add_argument("--config", type=Path, help=f"drivers YAML (default {DEFAULT_CONFIG})")
    parser.add_argument("--no-open", action="store_true", help="do not open the camera at start")
    parser.add_argument("--data", type=Path, default=default_data_dir(),
                        help="data directory: images go under DATA/tof/ (default: the server's, %(default)s)")
    parser.add_argument("-c", "--command", action="append", default=[],
                        help="run this line (';' separates several) and exit; repeatable")
    args = parser.parse_args(argv)

    try:
        # drivers.tof.create defaults the backend to sim too, so the default only matters with no file.
        config = load_section("tof", {"backend": "sim"}, args.config)
        if args.backend:
            config["backend"] = args.backend
        if args.serial is not None:
            config["serial"] = parse_serial(args.serial)
        if args.library:
            config["library"] = args.library
        if args.settings:
            config["settings_file"] = str(args.settings)
        from . import create

        settings = BACKENDS.settings(config)
        world = None
        if settings.backend == "sim":
            from drivers.sim.world import World

            world = World.from_scene(args.scene, seed=settings.seed)
        camera = create(settings, world)
    except SETUP_ERRORS as exc:
        print(f"rvs-tof: {one_line(exc)}", file=sys.stderr)
        return 2
    return run(TofConsole(camera, world, data_dir=args.data), args.command, start=None if args.no_open else "open",
               close=camera.close)


if __name__ == "__main__":
    sys.exit(main())
