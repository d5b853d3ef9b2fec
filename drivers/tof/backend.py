"""The small surface each SR4000 backend fills in (pyusb's IBackend idea).

A backend speaks libMesaSR's vocabulary: raw 16-bit images and register values. Everything
above it (frame integration, confidence masking, auto-exposure settling, undistortion, settings
files) lives once in :mod:`drivers.tof.device` and never knows which backend it drives.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np


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
    name: str
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
