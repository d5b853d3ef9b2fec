"""rvs-cam: an interactive console over the stereo driver, like the thesis's rvs-cam (sect. 4.1.6).

Every public function of the pair is a command; every error is caught and printed, so a failing
camera never ends the session. ``-c "command"`` runs lines non-interactively (repeatable); the
exit status is 1 if any of them failed, 2 if the console could not start (a bad option or config).
One-shot, stdout holds only the commands' results (``rvs-cam -c calibration > calib.yaml`` is the
calibration YAML rvs-stereo and rvs-odometry read); the echoed command lines, the cameras' ids
from start-up, warnings and errors go to stderr. Images go under ``--data DIR/stereo/`` (the server's data
directory by default): a relative FILE is taken there, an absolute one as it is; each grab prints
the absolute path it wrote.
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from drivers.console import (
    DEFAULT_CONFIG,
    SETUP_ERRORS,
    DeviceConsole,
    default_data_dir,
    one_line,
    read_config,
    run,
    split_words,
)
from drivers.stereo import BACKENDS, create
from drivers.stereo.modes import PIXEL_FORMATS, RESOLUTIONS, SIDES
from rvs_params import assignments
from rvs_params.cli import ToolParser
from rvs_params.plain import plain


def save_image(path: str | Path, image: np.ndarray) -> Path:
    """TIFF through tifffile (RGB as is), anything else through OpenCV (RGB turned to BGR)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    if target.suffix.lower() in (".tif", ".tiff"):
        import tifffile

        tifffile.imwrite(target, image, photometric="rgb" if image.ndim == 3 else "minisblack")
    else:
        import cv2

        out = image[..., ::-1] if image.ndim == 3 else image
        if not cv2.imwrite(str(target), np.ascontiguousarray(out)):
            raise ValueError(f"cannot write {target}: unknown image extension")
    return target


class CamShell(DeviceConsole):
    tool = "rvs-cam"
    intro = "rvs-cam: PIKE stereo pair console. 'help' lists commands, 'quit' leaves."
    prompt = "rvs-cam> "
    # rvs-cam's contract, which scripts driving it rely on: every error names its type, and Ctrl-C
    # ends the session (main closes the cameras on the way out) instead of returning to the prompt.
    plain_errors = ()
    catch_interrupts = False
    unknown_hint = "'help' lists commands"

    def __init__(self, camera: Any, trigger: Any = None, data_dir: str | Path | None = None, stdout: Any = None) -> None:
        super().__init__(stdout)
        self.cam = camera
        self.trigger = trigger
        self.out_dir = Path(data_dir if data_dir is not None else default_data_dir()) / "stereo"
        self.failed = 0

    # -- plumbing -----------------------------------------------------------------------------
    def fail(self, message: str) -> None:
        """rvs-cam's ``failed`` has always been a count of failed commands, not a flag."""
        self.failed += 1
        self.note(message)

    def precmd(self, line: str) -> str:
        head, _, rest = line.strip().partition(" ")
        return f"{head.replace('-', '_')} {rest}".strip()

    def commands_in(self, line: str) -> list[str]:
        """Each ``-c`` is one command (``;`` may be in a file name)."""
        return [line.strip()] if line.strip() else []

    def run_line(self, line: str) -> bool:
        """Each ``-c`` is one command, echoed after the prompt (a note) so the two streams read as a
        transcript on a terminal."""
        self.note(f"{self.prompt}{line}")
        return self.onecmd(self.precmd(line))

    def show(self, data: Any) -> None:
        self.say(yaml.safe_dump(plain(data, decimals=6), sort_keys=False).rstrip())

    def _grab_args(self, arg: str, default_name: str) -> tuple[str, dict[str, str]]:
        tokens = shlex.split(arg)
        opts = assignments([t for t in tokens if "=" in t], flag="grab")
        names = [t for t in tokens if "=" not in t]
        unknown = sorted(set(opts) - {"res", "fmt"})
        if unknown:
            raise ValueError(f"unknown option(s) {', '.join(unknown)}; use res=<{'|'.join(RESOLUTIONS)}> fmt=<{'|'.join(PIXEL_FORMATS)}>")
        name = names[0] if names else f"{default_name}-{time.strftime('%Y%m%d-%H%M%S')}.tif"
        return str(self.out_dir / name), opts

    def _save(self, name: str, images: dict[str, np.ndarray]) -> None:
        base = Path(name)
        suffix = base.suffix or ".tif"
        for side, image in images.items():
            path = base if len(images) == 1 else base.with_name(f"{base.stem}_{side}{suffix}")
            if not path.suffix:
                path = path.with_suffix(suffix)
            save_image(path, image)
            shape = "x".join(str(v) for v in image.shape)
            self.say(f"{side}: {path.absolute()} ({shape}, mean {float(image.mean()):.1f})")

    # -- init / de-init -----------------------------------------------------------------------
    def do_init(self, arg: str) -> None:
        """init: initialise the library and open both cameras (RvsCam_InitLibrary)."""
        self.cam.open()
        self.show(self.cam.camera_ids())

    def do_deinit(self, arg: str) -> None:
        """deinit: close the cameras (RvsCam_DeInitLibrary)."""
        self.cam.close()
        self.say("closed")

    def do_reset(self, arg: str) -> None:
        """reset: full hardware reset of both cameras, then the default settings (RvsCam_Reset)."""
        self.cam.reset()
        self.say("reset done")

    def do_reinit(self, arg: str) -> None:
        """reinit: reopen the cameras and write the default settings (RvsCam_ReInit)."""
        self.cam.reinit()
        self.say("reinit done")

    def do_status(self, arg: str) -> None:
        """status: the thread-safe status structure of both cameras (RvsCam_GetStatus)."""
        self.show(self.cam.status())

    def do_check(self, arg: str) -> None:
        """check: talk to both cameras to prove they answer."""
        self.show(self.cam.check()["check"])

    # -- ids ------------------------------------------------------------------------------------
    def do_ids(self, arg: str) -> None:
        """ids: the left and right camera ids (RvsCam_GetCameraIDs)."""
        self.show(self.cam.camera_ids())

    def do_list(self, arg: str) -> None:
        """list: the camera ids found on the bus, in bus order."""
        self.show(self.cam.available_ids())

    def do_set_ids(self, arg: str) -> None:
        """set-ids LEFT RIGHT: choose the cameras by GUID or bus index (RvsCam_SetCameraIDs)."""
        parts = split_words(arg, 2, 2, "set-ids LEFT RIGHT")
        self.show(self.cam.set_camera_ids(parts[0], parts[1]))

    def do_swap_ids(self, arg: str) -> None:
        """swap-ids: exchange left and right (RvsCam_SwapCameraIDs)."""
        self.show(self.cam.swap_camera_ids())

    # -- settings -------------------------------------------------------------------------------
    def do_settings(self, arg: str) -> None:
        """settings [left|right]: the current settings (RvsCam_GetSettings)."""
        side = arg.strip() or None
        self.show(self.cam.get_settings(side))

    def do_set(self, arg: str) -> None:
        """set [left|right|both] key=value ...: e.g. set left shutter_us=4000 gain_db=6 (RvsCam_SetSettings)."""
        tokens = shlex.split(arg)
        side = "both"
        if tokens and "=" not in tokens[0]:
            side = tokens.pop(0)
        if not tokens:
            raise ValueError("usage: set [left|right|both] key=value ...")
        changes = assignments(tokens, flag="set")
        if "white_balance" in changes:
            changes["white_balance"] = changes["white_balance"].replace(",", " ")
        self.show(self.cam.set_settings(side, **changes))

    def do_load(self, arg: str) -> None:
        """load FILE: load both cameras' settings from YAML (RvsCam_LoadSettings)."""
        self.show(self.cam.load_settings(_one(arg, "load FILE")))

    def do_save(self, arg: str) -> None:
        """save FILE: save both cameras' settings to YAML (RvsCam_SaveSettings)."""
        self.say(f"saved {self.cam.save_settings(_one(arg, 'save FILE'))}")

    def do_mode(self, arg: str) -> None:
        """mode [RESOLUTION] [FORMAT]: default grab mode, e.g. mode highest rgb8 (low|medium|high|highest, mono8|rgb8)."""
        res = fmt = None
        for token in shlex.split(arg):
            # Resolution names are words, pixel formats carry a bit depth: route unknowns by that.
            if token.lower() in RESOLUTIONS or not any(c.isdigit() for c in token):
                res = token
            else:
                fmt = token
        self.show(self.cam.set_mode(res, fmt))

    def do_calibration(self, arg: str) -> None:
        """calibration [RESOLUTION]: K1 D1 K2 D2 R T image_size of the pair."""
        self.show(self.cam.calibration(arg.strip() or None))

    # -- grabs ----------------------------------------------------------------------------------
    def do_grab_stereo(self, arg: str) -> None:
        """grab-stereo [FILE] [res=..] [fmt=..]: both cameras on one trigger pulse; saves FILE_left/_right, relative to DATA/stereo (RvsCam_GrabStereo)."""
        name, o = self._grab_args(arg, "stereo")
        left, right = self.cam.grab_stereo(o.get("res"), o.get("fmt"))
        self._save(name, {"left": left, "right": right})

    def do_grab_stereo_direct(self, arg: str) -> None:
        """grab-stereo-direct [FILE] [res=..] [fmt=..]: both cameras free-running, no trigger (RvsCam_GrabStereoDirect)."""
        name, o = self._grab_args(arg, "stereo-direct")
        left, right = self.cam.grab_stereo_direct(o.get("res"), o.get("fmt"))
        self._save(name, {"left": left, "right": right})

    def do_grab_mono(self, arg: str) -> None:
        """grab-mono SIDE [FILE] [res=..] [fmt=..]: one camera on a trigger pulse (RvsCam_GrabMono)."""
        side, rest = _side_first(arg)
        name, o = self._grab_args(rest, f"mono-{side}")
        self._save(name, {side: self.cam.grab_mono(side, o.get("res"), o.get("fmt"))})

    def do_grab_mono_direct(self, arg: str) -> None:
        """grab-mono-direct SIDE [FILE] [res=..] [fmt=..]: one camera free-running (RvsCam_GrabMonoDirect)."""
        side, rest = _side_first(arg)
        name, o = self._grab_args(rest, f"mono-direct-{side}")
        self._save(name, {side: self.cam.grab_mono_direct(side, o.get("res"), o.get("fmt"))})

    def do_grab_left(self, arg: str) -> None:
        """grab-left [FILE] [res=..] [fmt=..]: the left camera on a trigger pulse (RvsCam_GrabLeft)."""
        name, o = self._grab_args(arg, "left")
        self._save(name, {"left": self.cam.grab_left(o.get("res"), o.get("fmt"))})

    def do_grab_right(self, arg: str) -> None:
        """grab-right [FILE] [res=..] [fmt=..]: the right camera on a trigger pulse (RvsCam_GrabRight)."""
        name, o = self._grab_args(arg, "right")
        self._save(name, {"right": self.cam.grab_right(o.get("res"), o.get("fmt"))})

    # -- trigger and faults ---------------------------------------------------------------------
    def do_pulse(self, arg: str) -> None:
        """pulse: fire the trigger box once."""
        if self.trigger is None:
            raise ValueError("no trigger box attached")
        self.say(f"pulse {self.trigger.pulse()}")

    def do_fault(self, arg: str) -> None:
        """fault KIND|none [left|right]: inject a simulated fault (no_trigger, unplug) or clear it."""
        parts = shlex.split(arg)
        if not parts:
            raise ValueError("usage: fault KIND|none [left|right]")
        kind = None if parts[0].lower() in ("none", "clear", "off") else parts[0]
        self.cam.inject_fault(kind, parts[1] if len(parts) > 1 else None)
        self.say(f"fault {kind}")

    def do_quit(self, arg: str) -> bool:
        """quit: close the cameras and leave."""
        return True

    do_exit = do_EOF = do_quit  # EOF leaves without the blank line the other consoles print


def _one(arg: str, usage: str) -> str:
    return split_words(arg, 1, 1, usage)[0]


def _side_first(arg: str) -> tuple[str, str]:
    parts = arg.strip().split(None, 1)
    if not parts or parts[0].lower() not in SIDES:
        raise ValueError(f"usage: grab-mono {'|'.join(SIDES)} [FILE] [res=..] [fmt=..]")
    return parts[0].lower(), parts[1] if len(parts) > 1 else ""


def load_config(path: str | Path | None) -> dict[str, Any]:
    """The whole file, as rvs-cam reads both its stereo and its trigger section."""
    if path and not Path(path).exists():
        raise FileNotFoundError(f"config file {Path(path)} not found")
    return read_config(path) or {}


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = ToolParser(prog="rvs-cam", description=__doc__)
    p.add_argument("--config", help=f"drivers.yaml to read (default {DEFAULT_CONFIG})")
    p.add_argument("--backend", choices=BACKENDS.names(), help="camera backend (default: from the config)")
    p.add_argument("--left-id", help="left camera GUID (hex) or bus index")
    p.add_argument("--right-id", help="right camera GUID (hex) or bus index")
    p.add_argument("--trigger-backend", choices=("sim", "ppdev", "none"), help="trigger box backend")
    p.add_argument("--trigger-device", help="parallel port of the trigger box, e.g. /dev/parport0")
    p.add_argument("--library", help="path of libdc1394")
    p.add_argument("--scene", default="office", help="simulated scene (sim backend)")
    p.add_argument("--resolution", choices=tuple(RESOLUTIONS), help="default grab resolution")
    p.add_argument("--pixel-format", choices=PIXEL_FORMATS, help="default pixel format")
    p.add_argument("--data", type=Path, default=default_data_dir(),
                   help="data directory: images go under DATA/stereo/ (default: the server's, %(default)s)")
    p.add_argument("-c", dest="commands", action="append", default=[], help="run this command line and exit (repeatable)")
    return p.parse_args(argv)


def main(argv: list[str] | None = None, *, world: Any = None, stdout: Any = None, stderr: Any = None) -> int:
    args = parse_args(argv)
    out = stdout or sys.stdout
    err = stderr or sys.stderr
    try:
        settings, trg_cfg, world = _setup(args, world)
    except SETUP_ERRORS as exc:
        print(f"rvs-cam: {one_line(exc)}", file=err)
        return 2

    trigger = None
    if trg_cfg["backend"] != "none":
        from drivers import trigger as trigger_pkg

        try:
            trigger = trigger_pkg.create(trg_cfg, world)
            trigger.open()
        except Exception as exc:
            print(f"warning: trigger box unavailable ({one_line(exc)}); only direct grabs will work", file=err)
            trigger = None
    camera = create(settings, world, trigger)
    shell = CamShell(camera, trigger, args.data, stdout=out)
    try:
        return run(shell, args.commands, start="init", prompt_status=True, notes=err)
    finally:
        # Not run(close=...): a camera or trigger that fails to close is worth a traceback here.
        try:
            camera.close()
        finally:
            if trigger is not None:
                trigger.close()


def _setup(args: argparse.Namespace, world: Any) -> tuple[Any, dict[str, Any], Any]:
    """The camera settings, the trigger's config and the simulated world from the options and the
    config file; raises one of SETUP_ERRORS on bad input."""
    config = load_config(args.config)
    cam_cfg = dict(config.get("stereo") or {})
    trg_cfg = dict(config.get("trigger") or {})
    for key, value in (
        ("backend", args.backend),
        ("left_id", args.left_id),
        ("right_id", args.right_id),
        ("library", args.library),
        ("resolution", args.resolution),
        ("pixel_format", args.pixel_format),
    ):
        if value is not None:
            cam_cfg[key] = value
    settings = BACKENDS.settings(cam_cfg)
    # Real cameras want the real box and simulated cameras the simulated one, unless told otherwise.
    trg_cfg["backend"] = args.trigger_backend or ("sim" if settings.backend == "sim" else "ppdev")
    if args.trigger_device:
        trg_cfg["device"] = args.trigger_device
    if settings.backend == "sim" and world is None:
        from drivers.sim.world import World

        world = World.from_scene(args.scene, seed=settings.seed)
    return settings, trg_cfg, world


if __name__ == "__main__":
    raise SystemExit(main())
