"""The stereo pair front end: rvs-libcam-avt's functions over a camera backend (sim or dc1394).

It owns what the thesis's library kept in globals: the camera id structure (left/right GUIDs,
swappable), the per-camera settings, and a per-camera status structure that other threads can
read at any time (its own lock, never held while the cameras work). Backends only know cameras
by GUID; this class maps sides to GUIDs and turns backend failures into DeviceError messages
that name the side and the id.
"""

from __future__ import annotations

import copy
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from drivers.base import Cancel, DeviceError
from drivers.registry import Capability
from drivers.stereo import calibration as calib_file
from drivers.stereo.backend import BACKENDS, CameraBackend, StereoSettings
from drivers.stereo.errors import CameraLost, GrabCancelled, MissedTrigger
from drivers.stereo.modes import SIDES, check_pixel_format, check_resolution, check_side, resolution_size
from drivers.stereo.settings import (
    CameraSettings,
    defaults_from_config,
    load_settings_file,
    save_settings_file,
)
from rvs_params import Settings

NAME = "stereo"


@runtime_checkable
class Pulser(Protocol):
    """A trigger box: ``pulse()`` fires both cameras (drivers.trigger.Trigger is one)."""

    def pulse(self) -> int: ...


class StereoPair:
    """Thread-safe: grabs and settings changes are serialised; status() never waits for them."""

    name = NAME

    def __init__(self, config: Mapping[str, Any] | Settings, backend: CameraBackend, trigger: Any = None) -> None:
        """``config``: the drivers.stereo settings (typed; a mapping is typed first)."""
        self.config: StereoSettings = BACKENDS.settings(config)
        self._backend = backend
        self.backend = backend.name
        self.capabilities = backend.capabilities
        self._wanted = {"left": self.config.left_id, "right": self.config.right_id}
        self.resolution = check_resolution(self.config.resolution)
        self.pixel_format = check_pixel_format(self.config.pixel_format)
        self.trigger_timeout = self.config.trigger_timeout
        self.direct_timeout = self.config.direct_timeout
        self._defaults = defaults_from_config(self.config)
        self._settings: dict[str, CameraSettings] = dict.fromkeys(SIDES, self._defaults)
        self._ids: dict[str, str | None] = dict.fromkeys(SIDES)
        self._available: list[str] = []
        self._fire: Callable[[], Any] | None = None
        self.set_trigger(trigger)
        self._op = threading.RLock()
        self._st = threading.Lock()
        self._status: dict[str, Any] = {
            "open": False,
            "grabs": 0,
            "last_grab": None,
            "last_error": None,
            **{side: self._side_status("closed") for side in SIDES},
        }

    # -- init / de-init (RvsCam_InitLibrary / RvsCam_DeInitLibrary) ------------------------------------
    def open(self) -> None:
        with self._op:
            try:
                self._available = list(self._backend.open())
                ids = self._resolve(self._wanted)
                for side in SIDES:
                    self._backend.apply_settings(ids[side], self._settings[side])
            except CameraLost as exc:
                self._close_quietly()
                raise self._lost_error(exc) from exc
            except DeviceError:
                self._close_quietly()
                raise
            self._ids = dict(ids)
            settings_file = self.config.settings_file
            if settings_file and Path(settings_file).exists():
                self._load_settings_locked(settings_file)
            with self._st:
                self._status["open"] = True
                self._status["last_error"] = None
                for side in SIDES:
                    self._status[side] = self._side_status("idle")
                    self._status[side]["id"] = ids[side]
                    self._status[side]["settings"] = self._settings[side].to_dict()

    init = open

    def close(self) -> None:
        with self._op:
            self._close_quietly()

    deinit = close

    def _close_quietly(self) -> None:
        try:
            self._backend.close()
        finally:
            with self._st:
                self._status["open"] = False
                for side in SIDES:
                    self._status[side]["state"] = "closed"

    def reinit(self) -> None:
        """Re-open the cameras and write the default settings again (RvsCam_ReInit)."""
        with self._op:
            self._settings = dict.fromkeys(SIDES, self._defaults)
            self._close_quietly()
            self.open()

    def reset(self, cancel: Cancel = None) -> None:
        """Full hardware reset of both cameras, then defaults (RvsCam_Reset)."""
        with self._op:
            if self._status["open"]:
                try:
                    self._backend.hardware_reset([g for g in self._ids.values() if g])
                except CameraLost as exc:
                    self._close_quietly()
                    raise self._lost_error(exc) from exc
            self.reinit()

    def reconfigure(self, settings: Settings) -> list[str]:
        """The pair takes no setting while open: every change waits for its reinit."""
        return []

    def attach(self, kind: str, device: Any) -> None:
        """A peer (drivers.stereo.PEERS) was rebuilt: fire the new trigger box from now on."""
        if kind == "trigger":
            self.set_trigger(device)

    def set_trigger(self, trigger: Any) -> None:
        """Attach the trigger box: an object with ``pulse()`` or a plain callable."""
        if trigger is None:
            self._fire = None
        elif isinstance(trigger, Pulser):
            self._fire = trigger.pulse
        elif callable(trigger):
            self._fire = trigger
        else:
            raise TypeError("trigger must have a pulse() method or be callable")

    # -- camera ids (RvsCam_Get/Set/SwapCameraIDs) ----------------------------------------------------
    def camera_ids(self) -> dict[str, str | None]:
        with self._st:
            return {side: self._status[side]["id"] for side in SIDES}

    def available_ids(self) -> list[str]:
        with self._op:
            self._require_open()
            return list(self._backend.available())

    def set_camera_ids(self, left: str, right: str) -> dict[str, str | None]:
        """Choose cameras by GUID (hex) or by index in the bus order ("0", "1")."""
        with self._op:
            self._require_open()
            self._available = list(self._backend.available())
            ids = self._resolve({"left": str(left), "right": str(right)})
            self._ids = dict(ids)
            self._wanted = dict(ids)
            try:
                for side in SIDES:
                    self._backend.apply_settings(ids[side], self._settings[side])
            except CameraLost as exc:
                raise self._lost_error(exc) from exc
            with self._st:
                for side in SIDES:
                    self._status[side]["id"] = ids[side]
            return self.camera_ids()

    def swap_camera_ids(self) -> dict[str, str | None]:
        with self._op:
            self._require_open()
            left, right = self._ids["left"], self._ids["right"]
            self._ids = {"left": right, "right": left}
            self._wanted = {"left": str(right), "right": str(left)}
            self._settings = {"left": self._settings["right"], "right": self._settings["left"]}
            with self._st:
                self._status["left"]["id"], self._status["right"]["id"] = right, left
            return self.camera_ids()

    def _resolve(self, wanted: dict[str, str]) -> dict[str, str]:
        found = self._available
        if not found:
            raise DeviceError(
                NAME,
                f"no FireWire cameras found (wanted left {wanted['left']}, right {wanted['right']}): check the "
                "cables, the camera power from the trigger box and the FireWire permissions",
            )
        ids: dict[str, str] = {}
        for side in SIDES:
            want = wanted[side].strip().lower()
            if want.isdigit() and len(want) <= 2:
                index = int(want)
                if index >= len(found):
                    raise DeviceError(
                        NAME,
                        f"{side} camera id {want} means camera #{index} on the bus, but only {len(found)} "
                        f"found ({', '.join(found)}); wanted left {wanted['left']}, right {wanted['right']}",
                    )
                ids[side] = found[index]
            else:
                guid = want.removeprefix("0x").rjust(16, "0")
                if guid not in found:
                    raise DeviceError(
                        NAME,
                        f"{side} camera {want} not found on the bus (found: {', '.join(found)}); wanted left "
                        f"{wanted['left']}, right {wanted['right']}: check the GUIDs in drivers.stereo.left_id/right_id",
                    )
                ids[side] = guid
        if ids["left"] == ids["right"]:
            raise ValueError(f"left and right must be different cameras, both are {ids['left']}")
        return ids

    # -- settings (RvsCam_Get/Set/Load/SaveSettings) ----------------------------------------------------
    def get_settings(self, side: str | None = None) -> dict[str, Any]:
        """Settings of one side, or of both as {"left": {...}, "right": {...}}."""
        with self._op:
            if side is None:
                return {s: self._settings[s].to_dict() for s in SIDES}
            return self._settings[check_side(side)].to_dict()

    def set_settings(self, side: str = "both", **changes: Any) -> dict[str, Any]:
        """Change some settings of "left", "right" or "both"; ValueError on a bad name or value."""
        sides = SIDES if side == "both" else (check_side(side),)
        with self._op:
            new = {s: self._settings[s].replace(**changes) for s in sides}  # validate before touching
            self._apply(new)
            return self.get_settings(None if side == "both" else sides[0])

    def load_settings(self, path: str | Path) -> dict[str, Any]:
        with self._op:
            self._load_settings_locked(path)
            return self.get_settings()

    def _load_settings_locked(self, path: str | Path) -> None:
        self._apply(load_settings_file(path, self._settings))

    def save_settings(self, path: str | Path) -> Path:
        with self._op:
            return save_settings_file(path, self._settings)

    def _apply(self, new: dict[str, CameraSettings]) -> None:
        if self._status["open"]:
            for side, settings in new.items():
                guid = self._ids[side]
                try:
                    self._backend.apply_settings(guid, settings)
                except CameraLost as exc:
                    raise self._lost_error(exc) from exc
        self._settings.update(new)
        with self._st:
            for side in new:
                self._status[side]["settings"] = self._settings[side].to_dict()

    def set_mode(self, resolution: str | None = None, pixel_format: str | None = None) -> dict[str, str]:
        """Default resolution and pixel format for grabs that do not name their own."""
        with self._op:
            if resolution is not None:
                self.resolution = check_resolution(resolution)
            if pixel_format is not None:
                self.pixel_format = check_pixel_format(pixel_format)
            return {"resolution": self.resolution, "pixel_format": self.pixel_format}

    # -- image acquisition ------------------------------------------------------------------------------
    def grab_stereo(
        self,
        resolution: str | None = None,
        pixel_format: str | None = None,
        cancel: Any = None,
        fire: bool = True,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Both cameras on one trigger pulse. ``fire=False`` waits for a pulse someone else fires."""
        frames = self._grab(SIDES, resolution, pixel_format, cancel, triggered=True, fire=fire)
        return frames["left"], frames["right"]

    def grab_mono(
        self,
        side: str = "left",
        resolution: str | None = None,
        pixel_format: str | None = None,
        cancel: Any = None,
        fire: bool = True,
    ) -> np.ndarray:
        """One camera, captured on a trigger pulse."""
        side = check_side(side)
        return self._grab((side,), resolution, pixel_format, cancel, triggered=True, fire=fire)[side]

    def grab_left(self, resolution: str | None = None, pixel_format: str | None = None, cancel: Any = None) -> np.ndarray:
        return self.grab_mono("left", resolution, pixel_format, cancel)

    def grab_right(self, resolution: str | None = None, pixel_format: str | None = None, cancel: Any = None) -> np.ndarray:
        return self.grab_mono("right", resolution, pixel_format, cancel)

    def grab_stereo_direct(
        self, resolution: str | None = None, pixel_format: str | None = None, cancel: Any = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Both cameras free-running, no trigger: the two images may be a frame apart."""
        frames = self._grab(SIDES, resolution, pixel_format, cancel, triggered=False)
        return frames["left"], frames["right"]

    def grab_mono_direct(
        self, side: str = "left", resolution: str | None = None, pixel_format: str | None = None, cancel: Any = None
    ) -> np.ndarray:
        side = check_side(side)
        return self._grab((side,), resolution, pixel_format, cancel, triggered=False)[side]

    def last_grab(self) -> dict[str, Any] | None:
        """Metadata of the last successful grab (for image sidecars)."""
        with self._st:
            return copy.deepcopy(self._status["last_grab"])

    def _grab(
        self,
        sides: tuple[str, ...],
        resolution: str | None,
        pixel_format: str | None,
        cancel: Any,
        triggered: bool,
        fire: bool = True,
    ) -> dict[str, np.ndarray]:
        res = check_resolution(resolution or self.resolution)
        fmt = check_pixel_format(pixel_format or self.pixel_format)
        size = resolution_size(res)
        with self._op:
            self._require_open()
            if triggered and fire and self._fire is None:
                raise DeviceError(
                    NAME,
                    "no trigger box attached: a triggered grab fires the trigger box (configure drivers.trigger), "
                    "or use the direct (free-running) grab",
                )
            guids = [self._ids[s] for s in sides]
            self._set_state(sides, "busy", "external" if triggered else "free")
            started = time.time()
            pulse = None
            try:
                if triggered:
                    token = self._backend.arm(guids, size, fmt)
                    try:
                        if fire:
                            assert self._fire is not None
                            pulse = self._fire()
                        raw = self._backend.collect(token, self._frame_timeout(sides, self.trigger_timeout), cancel)
                    finally:
                        self._backend.disarm(token)
                else:
                    timeout = self._frame_timeout(sides, self.direct_timeout)
                    raw = self._backend.capture_direct(guids, size, fmt, timeout, cancel)
            except MissedTrigger as exc:
                err = self._missed_error(exc)
                self._set_error(sides, err.message)
                raise err from exc
            except CameraLost as exc:
                err = self._lost_error(exc)
                self._set_error(sides, err.message)
                raise err from exc
            except DeviceError as exc:
                self._set_error(sides, f"{exc.device}: {exc.message}")
                raise
            except GrabCancelled:
                self._set_state(sides, "idle")
                raise
            except BaseException as exc:
                self._set_error(sides, repr(exc))
                raise
            frames = {side: raw[guid] for side, guid in zip(sides, guids, strict=True)}
            info = {
                "sides": list(sides),
                "ids": dict(zip(sides, guids, strict=True)),
                "resolution": res,
                "size": list(size),
                "pixel_format": fmt,
                "triggered": triggered,
                "pulse": pulse if isinstance(pulse, int) else None,
                "time": started,
                "duration_s": time.time() - started,
                "settings": {s: self._settings[s].to_dict() for s in sides},
            }
            if Capability.TRUTH in self.capabilities:
                shutters = self._backend.last_shutter()
                info["effective_shutter_us"] = {s: shutters.get(g) for s, g in zip(sides, guids, strict=True)}
            with self._st:
                self._status["grabs"] += 1
                self._status["last_grab"] = info
                self._status["last_error"] = None
                for side in sides:
                    self._status[side]["state"] = "idle"
                    self._status[side]["frames"] += 1
                    self._status[side]["last_error"] = None
            return frames

    def _frame_timeout(self, sides: tuple[str, ...], base: float) -> float:
        """A frame cannot arrive before its exposure ends: long shutters extend the wait."""
        exposure = max(0 if self._settings[s].auto_exposure else self._settings[s].shutter_us for s in sides)
        return base + exposure / 1e6

    # -- calibration ------------------------------------------------------------------------------------
    def calibration(self, resolution: str | None = None) -> dict[str, Any]:
        """K1 D1 K2 D2 R T image_size: the world's truth (sim) or the configured YAML file (real)."""
        size = resolution_size(check_resolution(resolution or self.resolution))
        with self._op:
            path = self.config.calibration
            if path:
                return calib_file.load_calibration(path, size)
            if Capability.TRUTH not in self.capabilities:
                raise DeviceError(
                    NAME,
                    "no stereo calibration configured: set drivers.stereo.calibration to a YAML file with "
                    "K1 D1 K2 D2 R T image_size (OpenCV stereoCalibrate names)",
                )
            self._require_open()
            return self._backend.calibration(self._ids["left"], self._ids["right"], size)

    # -- maintenance ------------------------------------------------------------------------------------
    def status(self) -> dict[str, Any]:
        with self._st:
            snap = copy.deepcopy(self._status)
        snap.update(
            backend=self.backend,
            busy=any(snap[s]["state"] == "busy" for s in SIDES),
            resolution=self.resolution,
            pixel_format=self.pixel_format,
            trigger_timeout=self.trigger_timeout,
            trigger_attached=self._fire is not None,
        )
        if Capability.FAULTS in self.capabilities:
            faults = self._backend.active_faults()
            snap["faults"] = {s: faults.get(snap[s]["id"]) for s in SIDES}
        return snap

    def check(self) -> dict[str, Any]:
        with self._op:
            self._require_open()
            try:
                answers = self._backend.check([self._ids[s] for s in SIDES])
            except CameraLost as exc:
                err = self._lost_error(exc)
                self._set_error(SIDES, err.message)
                raise err from exc
        result = self.status()
        result["check"] = {s: answers.get(self._ids[s]) for s in SIDES}
        return result

    def inject_fault(self, kind: str | None, side: str | None = None) -> None:
        """Simulated backend only: ``no_trigger``, ``unplug`` or None, for one side or both."""
        if Capability.FAULTS not in self.capabilities:
            raise ValueError(f"fault injection needs the sim backend, this is {self.backend}")
        inject = self._backend.inject_fault
        with self._st:
            ids = {s: self._status[s]["id"] for s in SIDES}
        if side is None:
            inject(kind, None)
        else:
            guid = ids[check_side(side)]
            if guid is None:
                raise ValueError("open the cameras before injecting a fault into one side")
            inject(kind, [guid])

    # -- helpers ----------------------------------------------------------------------------------------
    def _require_open(self) -> None:
        if not self._status["open"]:
            raise DeviceError(NAME, "stereo cameras are not initialised (open/init, or reinit after a fault)")

    def _side_of(self, guid: str) -> str:
        for side in SIDES:
            if self._ids.get(side) == guid:
                return side
        return "unassigned"

    def _missed_error(self, exc: MissedTrigger) -> DeviceError:
        named = [f"{g} ({self._side_of(g)})" for g in exc.guids]
        after = "" if exc.after is None else f" after pulse {exc.after + 1}"
        return DeviceError(
            NAME,
            f"camera {named[0]} missed its trigger: no frame within {exc.timeout:g} s{after}"
            + (f" (and camera {', '.join(named[1:])})" if len(named) > 1 else "")
            + "; check the trigger cable, the trigger box power and drivers.stereo.trigger_timeout",
        )

    def _lost_error(self, exc: CameraLost) -> DeviceError:
        detail = f" {exc.detail}" if exc.detail else ""
        return DeviceError(
            NAME,
            f"camera {exc.guid} ({self._side_of(exc.guid)}) is not answering on the FireWire bus{detail}: "
            "unplugged or unpowered? check the cable and the trigger box power, then reinit",
        )

    def _side_status(self, state: str) -> dict[str, Any]:
        return {
            "id": None,
            "state": state,
            "trigger_mode": "external",
            "frames": 0,
            "last_error": None,
            "settings": self._defaults.to_dict(),
        }

    def _set_state(self, sides: tuple[str, ...], state: str, trigger_mode: str | None = None) -> None:
        with self._st:
            for side in sides:
                self._status[side]["state"] = state
                if trigger_mode is not None:
                    self._status[side]["trigger_mode"] = trigger_mode

    def _set_error(self, sides: tuple[str, ...], message: str) -> None:
        with self._st:
            self._status["last_error"] = message
            for side in sides:
                self._status[side]["state"] = "error"
                self._status[side]["last_error"] = message

    def __enter__(self) -> StereoPair:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
