"""The small surface each SR4000 backend fills in (pyusb's IBackend idea).

A backend speaks libMesaSR's vocabulary: raw 16-bit images and register values. Everything
above it (frame integration, confidence masking, auto-exposure settling, undistortion, settings
files) lives once in :mod:`drivers.tof.device` and never knows which backend it drives.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np

from drivers.registry import BackendRegistry, Capability
from rvs_params import Settings, param

from . import constants as k


@dataclass
class SR4000Settings(Settings):
    """drivers.tof keys of the front end (:class:`drivers.tof.device.Tof`), shared by all backends.

    The ``live`` ones are camera settings: an open camera takes a change of them at once
    (Tof.reconfigure); every other key waits for the device's next reinit or reset.
    """

    backend: str = param("sim", "ToF backend")
    serial: Any = param(0, "0 = first SR4000 on the USB bus; else hex as printed on the camera")
    timeout: float = param(2.0, "wait for a frame before DeviceError", unit="s", min=0.0, max=3600.0)
    modulation_mhz: float = param(30.0, "29/30/31/14.5/15/15.5 MHz; range c/2f: 5 m at 30 MHz, 10 m at 15 MHz",
                                  unit="MHz", min=1.0, max=100.0, live=True)
    integration: int = param(30, "integration register: 0.3 ms + 0.1 ms per step", min=0, max=255, live=True)
    amplitude_threshold: int = param(0, "pixels below this amplitude read 0", unit="counts", min=0, max=k.RAW_MAX,
                                     live=True)
    auto_exposure: bool = param(False, "let the camera choose the integration time", live=True)
    auto_exposure_params: dict = param(
        {"min_integration": 1, "max_integration": 150, "percent_over": 5, "desired": 70},
        "SR_SetAutoExposure's parameters", live=True)
    auto_exposure_max_iterations: int = param(20, "frames a grab spends letting auto exposure settle", min=1,
                                              max=10_000, live=True)
    corrections: list[str] = param(list(k.DEFAULT_CORRECTIONS),
                                   f"AcquireMode flags on, of {', '.join(k.CORRECTION_FLAGS)}", live=True)
    enhanced_xyz: bool = param(False, "AM_SHORT_RANGE: precise XYZ below 1 m", live=True)
    undistort: bool = param(True, "undistort 2-D grabs (XYZ images are already corrected by the camera)",
                            live=True)
    colour_range: dict = param({"distance": None, "amplitude": None, "confidence": [0.0, 1.0], "z": None},
                               "per image type: [low, high] mapped onto the fake colours, null = min..max",
                               live=True)
    camera_matrix: list | None = param(None, "3x3 list; null = the backend's (sim: the world's, mesasr: "
                                             "nominal from the FOV)")
    distortion: list[float] | None = param([0.0, 0.0, 0.0, 0.0, 0.0], "k1 k2 p1 p2 k3; null = the backend's; "
                                           "the sim renders with it, 2-D grabs remove it", length=(1, 5))
    settings_file: str | None = param(None, "YAML camera defaults loaded at open; created from the keys above "
                                            "if missing")


@dataclass
class RawFrame:
    """One SR_Acquire: the image list plus SR_CoordTrfFlt, as the camera delivered them.

    distance: uint16, 0..0xFFFF over the unambiguous range; 0 = below the amplitude threshold.
    amplitude: uint16 counts. confidence: uint16 (0xFFFF best) or None when AM_CONF_MAP is off.
    xyz: float32 (H, W, 3) metres in OpenCV's camera frame (x right, y down, z forward).
    integration: the register value the frame was taken with (auto exposure changes it).
    """

    distance: np.ndarray
    amplitude: np.ndarray
    confidence: np.ndarray | None
    xyz: np.ndarray
    integration: int


@dataclass
class DeviceInfo:
    serial: int
    vendor_id: int
    product_id: int
    manufacturer: str
    product: str
    device_string: str

    def as_dict(self) -> dict[str, Any]:
        return {
            "serial": f"0x{self.serial:08X}",
            "vendor_id": f"0x{self.vendor_id:04x}",
            "product_id": f"0x{self.product_id:04x}",
            "manufacturer": self.manufacturer,
            "product": self.product,
            "device_string": self.device_string,
        }


class Backend(Protocol):
    name: ClassVar[str]
    settings: ClassVar[type[Settings]]
    capabilities: ClassVar[frozenset[Capability]]
    faults: ClassVar[tuple[str, ...]]
    rows: int
    cols: int

    def open(self, serial: int) -> None:
        """SR_OpenUSB: 0 opens the first camera found. Raises DeviceError."""

    def close(self) -> None: ...

    @property
    def is_open(self) -> bool: ...

    def info(self) -> DeviceInfo:
        """SR_ReadSerial + SR_GetDeviceString."""

    def acquire(self) -> RawFrame:
        """SR_Acquire + SR_GetImageList + SR_CoordTrfFlt."""

    def set_integration(self, register: int) -> None: ...

    def get_integration(self) -> int: ...

    def set_modulation(self, frequency_mhz: float) -> None: ...

    def get_modulation(self) -> float: ...

    def set_amplitude_threshold(self, value: int) -> None: ...

    def set_mode(self, mode: int) -> None: ...

    def get_mode(self) -> int: ...

    def set_auto_exposure(self, min_integration: int, max_integration: int, percent_over: int, desired: int) -> None:
        """min_integration = 0xFF turns auto exposure off (libMesaSR convention)."""

    def intrinsics(self) -> tuple[np.ndarray, np.ndarray]:
        """Nominal camera matrix (3x3) and distortion (k1, k2, p1, p2, k3) of this camera."""

    # -- optional: only backends whose ``capabilities`` say so ------------------------------
    def inject_fault(self, kind: str | None, after: int = 0) -> None:
        """Capability.FAULTS: start one of ``faults`` (``after`` frames from now) or clear it (None)."""

    @property
    def fault(self) -> str | None:
        """Capability.FAULTS: the active fault, for the status snapshot."""

    def check_link(self) -> None:
        """Capability.LINK_CHECK: raise the backend's own DeviceError for a lost link."""


BACKENDS: BackendRegistry[Backend] = BackendRegistry("tof", SR4000Settings)
