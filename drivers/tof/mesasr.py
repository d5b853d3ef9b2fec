"""Real SR4000 backend: ctypes over MESA's libMesaSR (libmesasr.so).

Signatures follow libMesaSR.h/definesSR.h (2008+ API): the camera handle ``SRCAM`` is an
opaque pointer (c_void_p), SR_OpenUSB returns the number of cameras opened (<= 0 failed), images
come from SR_GetImageList as ``ImgEntry`` records, and SR_CoordTrfFlt fills three float arrays
in metres. libMesaSR's coordinate frame has x to the left and y up as seen from behind the
camera (ROS's swissranger driver negates both); this backend converts to OpenCV's frame
(x right, y down, z forward) so both backends return the same thing.

The library is loaded on ``open()``, so a machine without it can still build the device
registry; opening then fails with a DeviceError that says how to install it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import re
from ctypes import POINTER, c_char_p, c_float, c_int, c_ubyte, c_uint, c_ushort, c_void_p
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.base import DeviceError
from rvs_params import Settings, param

from . import constants as k
from .backend import BACKENDS, DeviceInfo, RawFrame
from .simulated import nominal_camera_matrix


class ImgEntry(ctypes.Structure):
    """definesSR.h ``struct _ImgEntry``."""

    _fields_ = [
        ("imgType", c_int),
        ("dataType", c_int),
        ("data", c_void_p),
        ("width", c_ushort),
        ("height", c_ushort),
    ]


DT_USHORT = 3

# name -> (restype, argtypes), from libMesaSR.h.
SIGNATURES: dict[str, tuple[Any, list[Any]]] = {
    "SR_OpenUSB": (c_int, [POINTER(c_void_p), c_uint]),
    "SR_Close": (c_int, [c_void_p]),
    "SR_Acquire": (c_int, [c_void_p]),
    "SR_GetImageList": (c_int, [c_void_p, POINTER(POINTER(ImgEntry))]),
    "SR_GetRows": (c_uint, [c_void_p]),
    "SR_GetCols": (c_uint, [c_void_p]),
    "SR_CoordTrfFlt": (c_int, [c_void_p, POINTER(c_float), POINTER(c_float), POINTER(c_float), c_int, c_int, c_int]),
    "SR_SetIntegrationTime": (c_int, [c_void_p, c_ubyte]),
    "SR_GetIntegrationTime": (c_ubyte, [c_void_p]),
    "SR_SetModulationFrequency": (c_int, [c_void_p, c_int]),
    "SR_GetModulationFrequency": (c_int, [c_void_p]),
    "SR_SetAmplitudeThreshold": (c_int, [c_void_p, c_ushort]),
    "SR_GetAmplitudeThreshold": (c_ushort, [c_void_p]),
    "SR_SetMode": (c_int, [c_void_p, c_int]),
    "SR_GetMode": (c_int, [c_void_p]),
    "SR_SetAutoExposure": (c_int, [c_void_p, c_ubyte, c_ubyte, c_ubyte, c_ubyte]),
    "SR_GetDeviceString": (c_int, [c_void_p, c_char_p, c_int]),
    "SR_ReadSerial": (c_uint, [c_void_p]),
    "SR_SetTimeout": (None, [c_void_p, c_int]),
    "SR_GetVersion": (c_int, [POINTER(c_ushort)]),
}

INSTALL_HELP = (
    "install MESA's libmesasr-dev package (libMesaSR for Linux, from MESA Imaging/Heptagon) "
    "or set drivers.tof.library to the full path of libmesasr.so"
)

_DEVICE_STRING = re.compile(
    r"VendorID:0x(?P<vid>[0-9a-fA-F]+),\s*ProductID:0x(?P<pid>[0-9a-fA-F]+),\s*"
    r"Manufacturer:'(?P<man>[^']*)',\s*Product:'(?P<prod>[^']*)'"
)


def declare(lib: Any) -> Any:
    """Set restype/argtypes of every function the backend calls; a missing symbol is an error."""
    missing = []
    for name, (restype, argtypes) in SIGNATURES.items():
        try:
            fn = getattr(lib, name)
        except AttributeError:
            missing.append(name)
            continue
        fn.restype = restype
        fn.argtypes = argtypes
    if missing:
        raise DeviceError("tof", f"libmesasr lacks {', '.join(missing)}: too old or not libMesaSR; {INSTALL_HELP}")
    return lib


def load_library(configured: str | None) -> Any:
    """The configured library if it loads, else the one ctypes.util finds as "mesasr"."""
    tried = []
    candidates = []
    if configured:
        candidates.append(str(configured))
    found = ctypes.util.find_library("mesasr")
    if found:
        candidates.append(found)
    for name in candidates:
        try:
            return declare(ctypes.CDLL(name))
        except OSError as exc:
            tried.append(f"{name}: {exc}")
    detail = "; ".join(tried) if tried else "ctypes.util.find_library('mesasr') found nothing"
    raise DeviceError("tof", f"libmesasr not found ({detail}); {INSTALL_HELP}")


def parse_device_string(text: str) -> tuple[int, int, str, str]:
    m = _DEVICE_STRING.search(text)
    if not m:
        return k.SR4000_VENDOR_ID, 0, "", text
    return int(m["vid"], 16), int(m["pid"], 16), m["man"], m["prod"]


@dataclass
class MesaSettings(Settings):
    library: str | None = param("libmesasr.so", "mesasr: tried first, then ctypes.util.find_library('mesasr')")


@BACKENDS.backend("mesasr")
class MesaSR:
    """libMesaSR over USB (register level)."""

    settings = MesaSettings

    def __init__(self, config: Any, world: Any = None) -> None:
        """``config``: the composed drivers.tof settings (SR4000Settings and MesaSettings keys)."""
        self._library_name = config.library
        self._timeout_ms = int(config.timeout * 1000)
        self._lib: Any = None
        self._handle = c_void_p()
        self._serial = 0
        self.rows, self.cols = k.HEIGHT, k.WIDTH

    @property
    def is_open(self) -> bool:
        return bool(self._handle.value)

    def open(self, serial: int) -> None:
        if self._lib is None:
            self._lib = load_library(self._library_name)
        handle = c_void_p()
        n = self._lib.SR_OpenUSB(ctypes.byref(handle), c_uint(serial))
        if n <= 0 or not handle.value:
            which = "no SR4000" if serial == 0 else f"no SR4000 with serial 0x{serial:08X}"
            raise DeviceError(
                "tof",
                f"{which} found on the USB bus (SR_OpenUSB returned {n}); check the cable, the power supply "
                "and USB permissions (udev rule for 1ad2:0074/0075), or use serial 0 for the first camera",
            )
        self._handle = handle
        self._serial = serial
        self._lib.SR_SetTimeout(self._handle, self._timeout_ms)
        self.rows = int(self._lib.SR_GetRows(self._handle))
        self.cols = int(self._lib.SR_GetCols(self._handle))

    def close(self) -> None:
        if self.is_open:
            try:
                self._lib.SR_Close(self._handle)
            finally:
                self._handle = c_void_p()

    def _h(self) -> c_void_p:
        if not self.is_open:
            raise DeviceError("tof", "SR4000 not open; run reinit or reset")
        return self._handle

    def _ok(self, result: int, call: str) -> int:
        if result < 0:
            raise DeviceError("tof", f"{call} failed ({result}) on camera 0x{self._serial:08X}: disconnected or not answering; reconnect, then reset")
        return result

    def info(self) -> DeviceInfo:
        h = self._h()
        serial = int(self._lib.SR_ReadSerial(h))
        buf = ctypes.create_string_buffer(256)
        self._lib.SR_GetDeviceString(h, buf, len(buf))
        text = buf.value.decode("latin-1", "replace")
        vid, pid, manufacturer, product = parse_device_string(text)
        return DeviceInfo(serial, vid, pid, manufacturer, product, text)

    def intrinsics(self) -> tuple[np.ndarray, np.ndarray]:
        # SR_CoordTrfFlt already corrects the optics; these nominal values only serve 2-D
        # undistortion until drivers.tof.camera_matrix/distortion hold a calibration.
        return nominal_camera_matrix(self.cols, self.rows), np.zeros(5)

    def set_integration(self, register: int) -> None:
        self._ok(self._lib.SR_SetIntegrationTime(self._h(), k.check_integration(register)), "SR_SetIntegrationTime")

    def get_integration(self) -> int:
        return int(self._lib.SR_GetIntegrationTime(self._h()))

    def set_modulation(self, frequency_mhz: float) -> None:
        code = k.SR4000_FREQUENCIES[k.check_frequency(frequency_mhz)]
        self._ok(self._lib.SR_SetModulationFrequency(self._h(), int(code)), "SR_SetModulationFrequency")

    def get_modulation(self) -> float:
        code = int(self._lib.SR_GetModulationFrequency(self._h()))
        for mhz, enum_value in k.SR4000_FREQUENCIES.items():
            if int(enum_value) == code:
                return mhz
        raise DeviceError("tof", f"camera reports modulation frequency code {code}, not an SR4000 frequency")

    def set_amplitude_threshold(self, value: int) -> None:
        self._ok(self._lib.SR_SetAmplitudeThreshold(self._h(), int(value)), "SR_SetAmplitudeThreshold")

    def set_mode(self, mode: int) -> None:
        self._ok(self._lib.SR_SetMode(self._h(), int(mode)), "SR_SetMode")

    def get_mode(self) -> int:
        return self._ok(int(self._lib.SR_GetMode(self._h())), "SR_GetMode")

    def set_auto_exposure(self, min_integration: int, max_integration: int, percent_over: int, desired: int) -> None:
        self._ok(
            self._lib.SR_SetAutoExposure(self._h(), min_integration, max_integration, percent_over, desired),
            "SR_SetAutoExposure",
        )

    def acquire(self) -> RawFrame:
        h = self._h()
        self._ok(self._lib.SR_Acquire(h), "SR_Acquire")
        entries = POINTER(ImgEntry)()
        n = self._ok(self._lib.SR_GetImageList(h, ctypes.byref(entries)), "SR_GetImageList")
        images: dict[int, np.ndarray] = {}
        for i in range(n):
            e = entries[i]
            if e.dataType != DT_USHORT or not e.data:
                continue
            buf = ctypes.cast(e.data, POINTER(c_ushort))
            images[e.imgType] = np.ctypeslib.as_array(buf, shape=(e.height, e.width)).copy()
        if k.IT_DISTANCE not in images or k.IT_AMPLITUDE not in images:
            raise DeviceError("tof", f"SR_GetImageList gave no distance/amplitude image ({n} images)")
        size = self.rows * self.cols
        x, y, z = (np.empty(size, np.float32) for _ in range(3))
        fp = POINTER(c_float)
        self._ok(
            self._lib.SR_CoordTrfFlt(h, x.ctypes.data_as(fp), y.ctypes.data_as(fp), z.ctypes.data_as(fp), 4, 4, 4),
            "SR_CoordTrfFlt",
        )
        xyz = np.stack([-x, -y, z], axis=-1).reshape(self.rows, self.cols, 3)
        return RawFrame(
            distance=images[k.IT_DISTANCE],
            amplitude=images[k.IT_AMPLITUDE],
            confidence=images.get(k.IT_CONF_MAP),
            xyz=xyz,
            integration=self.get_integration(),
        )

    def library_version(self) -> str:
        if self._lib is None:
            self._lib = load_library(self._library_name)
        v = (c_ushort * 4)()
        self._lib.SR_GetVersion(v)
        return f"{v[3]}.{v[2]}.{v[1]}.{v[0]}"
