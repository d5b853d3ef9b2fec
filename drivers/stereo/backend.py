"""The surface each stereo camera backend fills in (pyusb's IBackend idea), and its settings.

A backend knows cameras by GUID only: enumerate, write settings, arm a triggered capture and
collect its frames, capture free-running, reset. Everything that knows sides, the trigger box,
the settings files and the status snapshot is :class:`drivers.stereo.pair.StereoPair`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np

from drivers.registry import BackendRegistry, Capability
from drivers.stereo.modes import PIXEL_FORMATS, RESOLUTIONS
from drivers.stereo.settings import CameraSettings, camera_key
from rvs_params import Settings, param


@dataclass
class StereoSettings(Settings):
    """drivers.stereo keys of the front end, shared by all backends. The camera settings
    (shutter_us .. auto_exposure) are the power-up settings of both cameras: reinit and reset
    write them again."""

    backend: str = param("sim", "stereo camera backend")
    left_id: str = param("0", "left camera GUID (hex); \"0\"/\"1\" = first/second found")
    right_id: str = param("1", "right camera GUID (hex)")
    resolution: str = param("high", "default grab resolution", choices=tuple(RESOLUTIONS))
    pixel_format: str = param("mono8", "default grab pixel format", choices=PIXEL_FORMATS)
    shutter_us: int = camera_key("shutter_us")
    gain_db: float = camera_key("gain_db")
    white_balance: list[int] = camera_key("white_balance")
    target_grey: int = camera_key("target_grey")
    auto_exposure: bool = camera_key("auto_exposure")
    trigger_timeout: float = param(1.0, "a triggered grab waits this long for its frames before DeviceError",
                                   unit="s", min=0.0, max=3600.0)
    direct_timeout: float = param(2.0, "a free-running (direct) grab waits this long for a frame", unit="s",
                                  min=0.0, max=3600.0)
    calibration: str | None = param(None, "YAML with K1 D1 K2 D2 R T image_size; null = the sim's ground truth")
    settings_file: str | None = param(None, "camera settings YAML loaded at open when it exists "
                                             "(save/load-settings)")


class CameraBackend(Protocol):
    """Two cameras on one bus. Errors: CameraLost, MissedTrigger, GrabCancelled, DeviceError."""

    name: ClassVar[str]
    settings: ClassVar[type[Settings]]
    capabilities: ClassVar[frozenset[Capability]]
    faults: ClassVar[tuple[str, ...]]

    def open(self) -> list[str]:
        """Enumerate the bus; the GUIDs found."""

    def available(self) -> list[str]: ...

    def close(self) -> None: ...

    def describe(self, guid: str) -> dict[str, Any]: ...

    def apply_settings(self, guid: str, settings: CameraSettings) -> None: ...

    def hardware_reset(self, guids: list[str]) -> None: ...

    def check(self, guids: list[str]) -> dict[str, Any]: ...

    def arm(self, guids: list[str], size: tuple[int, int], pixel_format: str) -> dict[str, Any]:
        """Put the cameras in trigger mode; the token goes to collect or disarm."""

    def disarm(self, token: dict[str, Any]) -> None: ...

    def collect(self, token: dict[str, Any], timeout: float, cancel: Any = None) -> dict[str, np.ndarray]: ...

    def capture_direct(self, guids: list[str], size: tuple[int, int], pixel_format: str, timeout: float,
                       cancel: Any = None) -> dict[str, np.ndarray]: ...

    # -- optional: only backends whose ``capabilities`` say so ------------------------------
    def inject_fault(self, kind: str | None, guids: list[str] | None = None) -> None:
        """Capability.FAULTS: one of ``faults`` (or None) on these cameras (None = all)."""

    def active_faults(self) -> dict[str, str | None]:
        """Capability.FAULTS: per GUID, the fault in force."""

    def last_shutter(self) -> dict[str, float]:
        """Capability.TRUTH: per GUID, the shutter the last frame really had (auto exposure)."""

    def calibration(self, left: str, right: str, size: tuple[int, int]) -> dict[str, Any]:
        """Capability.TRUTH: the ground-truth K1 D1 K2 D2 R T image_size."""


BACKENDS: BackendRegistry[CameraBackend] = BackendRegistry("stereo", StereoSettings)
