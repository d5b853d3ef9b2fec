"""The real PIKE F-210B pair over FireWire through libdc1394 (ctypes).

Each camera runs Format7 mode 0 with a centred ROI of the requested resolution, in external
trigger mode 0 (one exposure per edge on the trigger input, which the LPT box drives) for the
triggered grabs, or free-running with the trigger off for the direct ones. Frames are copied
out of the DMA ring and the buffer is handed back at once, so the ring never fills.
"""

from __future__ import annotations

import ctypes
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.base import DeviceError
from drivers.stereo import dc1394_lib as dc
from drivers.stereo.backend import BACKENDS
from drivers.stereo.errors import CameraLost, GrabCancelled, MissedTrigger, is_cancelled
from drivers.stereo.modes import channels
from drivers.stereo.settings import CameraSettings
from rvs_params import Settings, param

NAME = "stereo"


@dataclass
class Dc1394Settings(Settings):
    """drivers.stereo keys of the FireWire backend."""

    library: str = param("libdc1394.so.25", "dc1394: the libdc1394 shared library")
    sensor_size: list[int] = param([1920, 1080], "dc1394: Format7 ROIs are centred on this sensor", unit="px",
                                   min=1, max=100_000, length=2)
    dma_buffers: int = param(4, "dc1394: capture ring size", min=1, max=64)
    poll_interval: float = param(0.002, "dc1394: how often a capture is polled for a frame", unit="s", min=0.0,
                                 max=1.0)
    reset_settle_s: float = param(0.5, "dc1394: wait after a bus reset before configuring again", unit="s",
                                  min=0.0, max=60.0)


@BACKENDS.backend("dc1394")
class Dc1394Cameras:
    settings = Dc1394Settings

    def __init__(self, config: Any, world: Any = None, *, lib: Any = None) -> None:
        """``config``: the composed drivers.stereo settings (StereoSettings and Dc1394Settings keys)."""
        self.library = config.library or "libdc1394.so.25"
        self.sensor_size = tuple(config.sensor_size)
        self.dma_buffers = config.dma_buffers
        self.poll_s = config.poll_interval
        self.reset_settle_s = config.reset_settle_s
        self._lib = lib  # injected by tests; loaded at open otherwise
        self._ctx: Any = None
        self._found: list[str] = []
        self._cams: dict[str, Any] = {}
        self._mode: dict[str, tuple[Any, ...]] = {}  # guid -> (size, format) of the running capture
        self._trigger_on: dict[str, bool] = {}
        self._lock = threading.RLock()

    # -- bus ---------------------------------------------------------------------------------
    def open(self) -> list[str]:
        with self._lock:
            if self._lib is None:
                self._lib = dc.load(self.library)
            if self._ctx is None:
                ctx = self._lib.dc1394_new()
                if not ctx:
                    raise DeviceError(
                        NAME,
                        "dc1394_new failed: no FireWire stack (load firewire-ohci, check /dev/fw* exists and "
                        "is readable by the video group)",
                    )
                self._ctx = ctx
            self._found = self._enumerate()
            return list(self._found)

    def _enumerate(self) -> list[str]:
        lst = ctypes.POINTER(dc.CameraList)()
        err = self._lib.dc1394_camera_enumerate(self._ctx, ctypes.pointer(lst))
        if err != dc.DC1394_SUCCESS:
            raise DeviceError(NAME, f"enumerating FireWire cameras failed: {dc.error_string(self._lib, err)}")
        guids: list[str] = []
        if lst:
            try:
                for i in range(lst.contents.num):
                    guid = f"{lst.contents.ids[i].guid:016x}"
                    if guid not in guids:  # multi-unit cameras list one GUID per unit
                        guids.append(guid)
            finally:
                self._lib.dc1394_camera_free_list(lst)
        return guids

    def available(self) -> list[str]:
        with self._lock:
            if self._ctx is None:
                return []
            self._found = self._enumerate()
            return list(self._found)

    def close(self) -> None:
        with self._lock:
            for guid in list(self._cams):
                self._release(guid)
            if self._ctx is not None and self._lib is not None:
                self._lib.dc1394_free(self._ctx)
            self._ctx = None

    def _release(self, guid: str) -> None:
        cam = self._cams.pop(guid, None)
        self._mode.pop(guid, None)
        self._trigger_on.pop(guid, None)
        if cam is None:
            return
        try:
            self._lib.dc1394_video_set_transmission(cam, dc.DC1394_OFF)
            self._lib.dc1394_capture_stop(cam)
        finally:
            self._lib.dc1394_camera_free(cam)

    def describe(self, guid: str) -> dict[str, Any]:
        cam = self._cams.get(guid)
        if cam is None:
            return {}
        info = cam.contents
        return {
            "vendor": (info.vendor or b"").decode(errors="replace"),
            "model": (info.model or b"").decode(errors="replace"),
        }

    def _cam(self, guid: str) -> Any:
        cam = self._cams.get(guid)
        if cam is not None:
            return cam
        if self._ctx is None:
            raise DeviceError(NAME, "libdc1394 is not initialised (open the cameras first)")
        cam = self._lib.dc1394_camera_new(self._ctx, int(guid, 16))
        if not cam:
            raise CameraLost(guid, "(dc1394_camera_new failed)")
        try:
            self._call(guid, "dc1394_video_set_operation_mode", cam, dc.DC1394_OPERATION_MODE_1394B)
            self._call(guid, "dc1394_video_set_iso_speed", cam, dc.DC1394_ISO_SPEED_800)
        except DeviceError:
            # A 1394a card or cable: legacy mode at 400 Mbit/s still works, just slower.
            self._call(guid, "dc1394_video_set_iso_speed", cam, dc.DC1394_ISO_SPEED_400)
        self._cams[guid] = cam
        return cam

    def _call(self, guid: str, fn: str, *args: Any, ignore: tuple[int, ...] = ()) -> int:
        err = getattr(self._lib, fn)(*args)
        if err != dc.DC1394_SUCCESS and err not in ignore:
            raise DeviceError(NAME, f"camera {guid}: {fn} failed: {dc.error_string(self._lib, err)}")
        return int(err)

    # -- settings ----------------------------------------------------------------------------
    def apply_settings(self, guid: str, s: CameraSettings) -> None:
        with self._lock:
            cam = self._cam(guid)
            call = self._call
            if s.auto_exposure:
                call(guid, "dc1394_feature_set_mode", cam, dc.DC1394_FEATURE_SHUTTER, dc.DC1394_FEATURE_MODE_AUTO)
            else:
                call(guid, "dc1394_feature_set_mode", cam, dc.DC1394_FEATURE_SHUTTER, dc.DC1394_FEATURE_MODE_MANUAL)
                call(guid, "dc1394_feature_set_absolute_control", cam, dc.DC1394_FEATURE_SHUTTER, dc.DC1394_ON)
                call(guid, "dc1394_feature_set_absolute_value", cam, dc.DC1394_FEATURE_SHUTTER, s.shutter_us * 1e-6)
            call(guid, "dc1394_feature_set_mode", cam, dc.DC1394_FEATURE_GAIN, dc.DC1394_FEATURE_MODE_MANUAL)
            call(guid, "dc1394_feature_set_absolute_control", cam, dc.DC1394_FEATURE_GAIN, dc.DC1394_ON)
            call(guid, "dc1394_feature_set_absolute_value", cam, dc.DC1394_FEATURE_GAIN, float(s.gain_db))
            # Mono PIKEs have no white balance; the target grey register is optional in IIDC.
            optional = (dc.DC1394_FUNCTION_NOT_SUPPORTED,)
            call(guid, "dc1394_feature_whitebalance_set_value", cam, *s.white_balance, ignore=optional)
            call(guid, "dc1394_feature_set_value", cam, dc.DC1394_FEATURE_EXPOSURE, s.target_grey, ignore=optional)

    def hardware_reset(self, guids: list[str]) -> None:
        with self._lock:
            for guid in guids:
                cam = self._cam(guid)
                self._call(guid, "dc1394_camera_reset", cam)
                self._release(guid)  # registers are back at power-up values: configure again
            time.sleep(self.reset_settle_s)

    def check(self, guids: list[str]) -> dict[str, Any]:
        out = {}
        with self._lock:
            for guid in guids:
                cam = self._cam(guid)
                value = ctypes.c_float()
                err = self._lib.dc1394_feature_get_absolute_value(cam, dc.DC1394_FEATURE_SHUTTER, ctypes.pointer(value))
                if err != dc.DC1394_SUCCESS:
                    raise CameraLost(guid, f"(reading the shutter failed: {dc.error_string(self._lib, err)})")
                out[guid] = {"responding": True, "shutter_us": round(value.value * 1e6), **self.describe(guid)}
        return out

    # -- capture -----------------------------------------------------------------------------
    def _configure(self, guid: str, size: tuple[int, int], pixel_format: str, triggered: bool) -> Any:
        cam = self._cam(guid)
        mode = (size, pixel_format)
        if self._mode.get(guid) != mode:
            if guid in self._mode:
                self._call(guid, "dc1394_video_set_transmission", cam, dc.DC1394_OFF)
                self._call(guid, "dc1394_capture_stop", cam)
                del self._mode[guid]
            w, h = size
            sw, sh = self.sensor_size
            if w > sw or h > sh:
                raise ValueError(f"resolution {w}x{h} exceeds the sensor's {sw}x{sh}")
            left, top = ((sw - w) // 2) & ~7, ((sh - h) // 2) & ~7  # Format7 position units
            self._call(guid, "dc1394_video_set_mode", cam, dc.DC1394_VIDEO_MODE_FORMAT7_0)
            self._call(
                guid, "dc1394_format7_set_roi", cam, dc.DC1394_VIDEO_MODE_FORMAT7_0,
                dc.COLOR_CODINGS[pixel_format], dc.DC1394_USE_MAX_AVAIL, left, top, w, h,
            )  # fmt: skip
            self._call(guid, "dc1394_external_trigger_set_mode", cam, dc.DC1394_TRIGGER_MODE_0)
            self._call(
                guid, "dc1394_external_trigger_set_source", cam, dc.DC1394_TRIGGER_SOURCE_0,
                ignore=(dc.DC1394_FUNCTION_NOT_SUPPORTED,),
            )  # fmt: skip
            self._call(guid, "dc1394_external_trigger_set_power", cam, dc.DC1394_ON if triggered else dc.DC1394_OFF)
            self._trigger_on[guid] = triggered
            self._call(guid, "dc1394_capture_setup", cam, self.dma_buffers, dc.DC1394_CAPTURE_FLAGS_DEFAULT)
            self._call(guid, "dc1394_video_set_transmission", cam, dc.DC1394_ON)
            self._mode[guid] = mode
        elif self._trigger_on.get(guid) != triggered:
            self._call(guid, "dc1394_external_trigger_set_power", cam, dc.DC1394_ON if triggered else dc.DC1394_OFF)
            self._trigger_on[guid] = triggered
        return cam

    def _poll(self, guid: str, cam: Any) -> Any:
        frame = ctypes.POINTER(dc.VideoFrame)()
        err = self._lib.dc1394_capture_dequeue(cam, dc.DC1394_CAPTURE_POLICY_POLL, ctypes.pointer(frame))
        if err != dc.DC1394_SUCCESS:
            raise CameraLost(guid, f"(dc1394_capture_dequeue: {dc.error_string(self._lib, err)})")
        return frame if frame else None

    def _flush(self, guid: str, cam: Any) -> None:
        """Drop frames already in the ring, so the next one is exposed after this call."""
        for _ in range(self.dma_buffers + 2):
            frame = self._poll(guid, cam)
            if frame is None:
                return
            self._lib.dc1394_capture_enqueue(cam, frame)

    def _copy(self, frame: Any, pixel_format: str) -> np.ndarray:
        f = frame.contents
        w, h = int(f.size[0]), int(f.size[1])
        ch = channels(pixel_format)
        stride = int(f.stride) or w * ch
        raw = ctypes.string_at(f.image, stride * h)
        rows = np.frombuffer(raw, dtype=np.uint8).reshape(h, stride)[:, : w * ch]
        return rows.reshape(h, w, ch).copy() if ch == 3 else rows.copy()

    def arm(self, guids: list[str], size: tuple[int, int], pixel_format: str) -> dict[str, Any]:
        with self._lock:
            for guid in guids:
                cam = self._configure(guid, size, pixel_format, triggered=True)
                self._flush(guid, cam)
        return {"guids": list(guids), "format": pixel_format}

    def disarm(self, token: dict[str, Any]) -> None:
        pass

    def collect(self, token: dict[str, Any], timeout: float, cancel: Any = None) -> dict[str, np.ndarray]:
        return self._wait_frames(token["guids"], token["format"], timeout, cancel, triggered=True)

    def capture_direct(
        self, guids: list[str], size: tuple[int, int], pixel_format: str, timeout: float, cancel: Any = None
    ) -> dict[str, np.ndarray]:
        with self._lock:
            for guid in guids:
                cam = self._configure(guid, size, pixel_format, triggered=False)
                self._flush(guid, cam)
        return self._wait_frames(guids, pixel_format, timeout, cancel, triggered=False)

    def _wait_frames(
        self, guids: list[str], pixel_format: str, timeout: float, cancel: Any, triggered: bool
    ) -> dict[str, np.ndarray]:
        deadline = time.monotonic() + timeout
        frames: dict[str, np.ndarray] = {}
        with self._lock:
            while len(frames) < len(guids):
                for guid in guids:
                    if guid in frames:
                        continue
                    cam = self._cams[guid]
                    frame = self._poll(guid, cam)
                    if frame is not None:
                        try:
                            frames[guid] = self._copy(frame, pixel_format)
                        finally:
                            self._lib.dc1394_capture_enqueue(cam, frame)
                if len(frames) == len(guids):
                    break
                if is_cancelled(cancel):
                    raise GrabCancelled("grab cancelled while waiting for frames")
                if time.monotonic() >= deadline:
                    missing = [g for g in guids if g not in frames]
                    if triggered:
                        raise MissedTrigger(missing, timeout)
                    raise CameraLost(missing[0], f"(no free-running frame within {timeout:g} s)")
                time.sleep(self.poll_s)
        return frames
