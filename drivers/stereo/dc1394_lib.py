"""ctypes declarations for the parts of libdc1394 2.x the PIKE pair needs.

Struct layouts and enum values are those of libdc1394 2.2 (dc1394/types.h, video.h, camera.h,
control.h), checked against the C headers: sizeof(dc1394video_frame_t) is 120 on LP64 with
``stride`` at byte 40 and ``image_bytes`` at 56 (the tests pin these offsets).
"""

from __future__ import annotations

import ctypes
import ctypes.util
from ctypes import POINTER, c_char_p, c_float, c_int, c_int32, c_uint16, c_uint32, c_uint64, c_void_p
from typing import Any

from drivers.base import DeviceError

# -- enums (libdc1394 2.2) -------------------------------------------------------------------------
DC1394_SUCCESS = 0
DC1394_FUNCTION_NOT_SUPPORTED = -3
DC1394_OFF, DC1394_ON = 0, 1
DC1394_ISO_SPEED_400, DC1394_ISO_SPEED_800 = 2, 3
DC1394_OPERATION_MODE_1394B = 481
DC1394_VIDEO_MODE_FORMAT7_0 = 88
DC1394_COLOR_CODING_MONO8 = 352
DC1394_COLOR_CODING_RGB8 = 356
DC1394_TRIGGER_MODE_0 = 384
DC1394_TRIGGER_SOURCE_0 = 576
DC1394_FEATURE_EXPOSURE = 417  # the auto-exposure reference: the PIKE's target grey level
DC1394_FEATURE_WHITE_BALANCE = 419
DC1394_FEATURE_SHUTTER = 423
DC1394_FEATURE_GAIN = 424
DC1394_FEATURE_MODE_MANUAL = 736
DC1394_FEATURE_MODE_AUTO = 737
DC1394_CAPTURE_POLICY_WAIT = 672
DC1394_CAPTURE_POLICY_POLL = 673
DC1394_CAPTURE_FLAGS_DEFAULT = 0x4
DC1394_USE_MAX_AVAIL = -2

COLOR_CODINGS = {"mono8": DC1394_COLOR_CODING_MONO8, "rgb8": DC1394_COLOR_CODING_RGB8}


class CameraId(ctypes.Structure):
    _fields_ = [("unit", c_uint16), ("guid", c_uint64)]


class CameraList(ctypes.Structure):
    _fields_ = [("num", c_uint32), ("ids", POINTER(CameraId))]


class Camera(ctypes.Structure):
    """dc1394camera_t up to the fields we read (guid, vendor, model); always used by pointer."""

    _fields_ = [
        ("guid", c_uint64),
        ("unit", c_int),
        ("unit_spec_ID", c_uint32),
        ("unit_sw_version", c_uint32),
        ("unit_sub_sw_version", c_uint32),
        ("command_registers_base", c_uint32),
        ("unit_directory", c_uint32),
        ("unit_dependent_directory", c_uint32),
        ("advanced_features_csr", c_uint64),
        ("PIO_control_csr", c_uint64),
        ("SIO_control_csr", c_uint64),
        ("strobe_control_csr", c_uint64),
        ("format7_csr", c_uint64 * 8),
        ("iidc_version", c_int),
        ("vendor", c_char_p),
        ("model", c_char_p),
        ("vendor_id", c_uint32),
        ("model_id", c_uint32),
    ]


class VideoFrame(ctypes.Structure):
    _fields_ = [
        ("image", POINTER(ctypes.c_ubyte)),
        ("size", c_uint32 * 2),
        ("position", c_uint32 * 2),
        ("color_coding", c_int),
        ("color_filter", c_int),
        ("yuv_byte_order", c_uint32),
        ("data_depth", c_uint32),
        ("stride", c_uint32),
        ("video_mode", c_int),
        ("total_bytes", c_uint64),
        ("image_bytes", c_uint32),
        ("padding_bytes", c_uint32),
        ("packet_size", c_uint32),
        ("packets_per_frame", c_uint32),
        ("timestamp", c_uint64),
        ("frames_behind", c_uint32),
        ("camera", c_void_p),
        ("id", c_uint32),
        ("allocated_image_bytes", c_uint64),
        ("little_endian", c_int),
        ("data_in_padding", c_int),
    ]


CAM = POINTER(Camera)
FRAME = POINTER(VideoFrame)

# name: (restype, argtypes)
PROTOTYPES: dict[str, tuple[Any, list[Any]]] = {
    "dc1394_new": (c_void_p, []),
    "dc1394_free": (None, [c_void_p]),
    "dc1394_camera_enumerate": (c_int, [c_void_p, POINTER(POINTER(CameraList))]),
    "dc1394_camera_free_list": (None, [POINTER(CameraList)]),
    "dc1394_camera_new": (CAM, [c_void_p, c_uint64]),
    "dc1394_camera_free": (None, [CAM]),
    "dc1394_camera_reset": (c_int, [CAM]),
    "dc1394_video_set_operation_mode": (c_int, [CAM, c_int]),
    "dc1394_video_set_iso_speed": (c_int, [CAM, c_int]),
    "dc1394_video_set_mode": (c_int, [CAM, c_int]),
    "dc1394_video_set_transmission": (c_int, [CAM, c_int]),
    "dc1394_format7_set_roi": (c_int, [CAM, c_int, c_int, c_int32, c_int32, c_int32, c_int32, c_int32]),
    "dc1394_external_trigger_set_mode": (c_int, [CAM, c_int]),
    "dc1394_external_trigger_set_source": (c_int, [CAM, c_int]),
    "dc1394_external_trigger_set_power": (c_int, [CAM, c_int]),
    "dc1394_capture_setup": (c_int, [CAM, c_uint32, c_uint32]),
    "dc1394_capture_stop": (c_int, [CAM]),
    "dc1394_capture_dequeue": (c_int, [CAM, c_int, POINTER(FRAME)]),
    "dc1394_capture_enqueue": (c_int, [CAM, FRAME]),
    "dc1394_feature_set_mode": (c_int, [CAM, c_int, c_int]),
    "dc1394_feature_set_value": (c_int, [CAM, c_int, c_uint32]),
    "dc1394_feature_set_absolute_control": (c_int, [CAM, c_int, c_int]),
    "dc1394_feature_set_absolute_value": (c_int, [CAM, c_int, c_float]),
    "dc1394_feature_get_absolute_value": (c_int, [CAM, c_int, POINTER(c_float)]),
    "dc1394_feature_whitebalance_set_value": (c_int, [CAM, c_uint32, c_uint32]),
    "dc1394_error_get_string": (c_char_p, [c_int]),
}

INSTALL_HINT = (
    "install it (`sudo apt install libdc1394-25`, or libdc1394-22 on older distributions) "
    "or set drivers.stereo.library to the library's path"
)


def load(library: str | None) -> Any:
    """Open libdc1394 and declare its prototypes; DeviceError naming the fix when it is absent."""
    candidates = [library] if library else []
    found = ctypes.util.find_library("dc1394")
    if found and found not in candidates:
        candidates.append(found)
    errors = []
    for name in candidates:
        try:
            lib = ctypes.CDLL(name)
        except OSError as exc:
            errors.append(f"{name}: {exc}")
            continue
        missing = [fn for fn in PROTOTYPES if not hasattr(lib, fn)]
        if missing:
            errors.append(f"{name} lacks {', '.join(missing[:3])} (not libdc1394 2.x?)")
            continue
        for fn, (restype, argtypes) in PROTOTYPES.items():
            func = getattr(lib, fn)
            func.restype = restype
            func.argtypes = argtypes
        return lib
    tried = "; ".join(errors) if errors else "no candidate library name"
    raise DeviceError("stereo", f"libdc1394 not found ({tried}): {INSTALL_HINT}")


def error_string(lib: Any, code: int) -> str:
    try:
        text = lib.dc1394_error_get_string(code)
    except Exception:  # a broken error path must not hide the original failure
        return f"error {code}"
    if isinstance(text, bytes):
        return text.decode(errors="replace")
    return str(text) if text else f"error {code}"
