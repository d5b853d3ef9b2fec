"""A fake libdc1394: two cameras that record every call and expose a frame per trigger pulse, for
the stereo pair's and the hazcams' FireWire backends alike (one fake for both bindings)."""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np

from drivers.stereo import dc1394_lib as dc

GUID_A = 0x000A47010E0A0001
GUID_B = 0x000A47010E0A0002
PAD = 16  # bytes of padding after each row, as Format7 packet rounding produces


class FakeCam:
    def __init__(self, guid: int, base: int) -> None:
        self.guid = guid
        self.base = base
        self.struct = dc.Camera(guid=guid, vendor=b"AVT", model=b"PIKE F-210B")
        self.roi: tuple[int, int, int] = (0, 0, 0)  # coding, w, h
        self.trigger = False
        self.transmitting = False
        self.queue: list[Any] = []
        self.keep: list[Any] = []

    def frame(self) -> Any:
        coding, w, h = self.roi
        ch = 3 if coding == dc.DC1394_COLOR_CODING_RGB8 else 1
        stride = w * ch + PAD
        rows = np.full((h, stride), 0xEE, np.uint8)
        rows[:, : w * ch] = pattern(self.base, w, h, ch).reshape(h, w * ch)
        buf = (ctypes.c_ubyte * rows.size).from_buffer_copy(rows.tobytes())
        frame = dc.VideoFrame(image=ctypes.cast(buf, ctypes.POINTER(ctypes.c_ubyte)), stride=stride, color_coding=coding)
        frame.size[0], frame.size[1] = w, h
        self.keep.append(buf)
        return frame


def pattern(base: int, w: int, h: int, ch: int) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w]
    img = (base + u + 3 * v) % 256
    if ch == 3:
        return np.stack([img, (img + 1) % 256, (img + 2) % 256], axis=-1).astype(np.uint8)
    return img.astype(np.uint8)


class FakeLib:
    """Enough of libdc1394 for the backend: records calls, makes frames on trigger or free-running."""

    def __init__(self, guids: tuple[int, ...] = (GUID_A, GUID_B)) -> None:
        self.guids = list(guids)
        self.calls: list[tuple[Any, ...]] = []
        self.cams: dict[int, FakeCam] = {}
        self.keep: list[Any] = []
        self.fail: dict[str, int] = {}
        self.freed: list[int] = []

    def __getattr__(self, name: str) -> Any:
        if name not in dc.PROTOTYPES:
            raise AttributeError(name)

        def record(*args: Any) -> int:
            self._log(name, args)
            return self.fail.get(name, 0)

        return record

    def _log(self, name: str, args: tuple[Any, ...]) -> None:
        if args and isinstance(args[0], ctypes.POINTER(dc.Camera)):
            self.calls.append((name, args[0].contents.guid, *args[1:]))
        else:
            self.calls.append((name, *args))

    def _cam(self, cam: Any) -> FakeCam:
        return self.cams[cam.contents.guid]

    def dc1394_new(self) -> int:
        return 0x1234

    def dc1394_free(self, ctx: int) -> None:
        self.calls.append(("dc1394_free",))

    def dc1394_camera_enumerate(self, ctx: int, out: Any) -> int:
        ids = (dc.CameraId * max(1, len(self.guids)))(*[dc.CameraId(0, g) for g in self.guids])
        lst = dc.CameraList(len(self.guids), ctypes.cast(ids, ctypes.POINTER(dc.CameraId)))
        self.keep += [ids, lst]
        out[0] = ctypes.pointer(lst)
        return 0

    def dc1394_camera_free_list(self, lst: Any) -> None:
        pass

    def dc1394_camera_new(self, ctx: int, guid: int) -> Any:
        if guid not in self.guids:
            return ctypes.POINTER(dc.Camera)()
        cam = self.cams.setdefault(guid, FakeCam(guid, base=40 * (self.guids.index(guid) + 1)))
        return ctypes.pointer(cam.struct)

    def dc1394_camera_free(self, cam: Any) -> None:
        self.freed.append(cam.contents.guid)

    def dc1394_format7_set_roi(self, cam: Any, mode: int, coding: int, packet: int, left: int, top: int, w: int, h: int) -> int:
        self._log("dc1394_format7_set_roi", (cam, mode, coding, packet, left, top, w, h))
        self._cam(cam).roi = (coding, w, h)
        return 0

    def dc1394_external_trigger_set_power(self, cam: Any, on: int) -> int:
        self._log("dc1394_external_trigger_set_power", (cam, on))
        self._cam(cam).trigger = bool(on)
        return 0

    def dc1394_video_set_transmission(self, cam: Any, on: int) -> int:
        self._log("dc1394_video_set_transmission", (cam, on))
        self._cam(cam).transmitting = bool(on)
        return 0

    def dc1394_capture_dequeue(self, cam: Any, policy: int, out: Any) -> int:
        if "dc1394_capture_dequeue" in self.fail:
            return self.fail["dc1394_capture_dequeue"]
        fake = self._cam(cam)
        if not fake.trigger and fake.transmitting and not fake.queue:
            fake.queue.append(fake.frame())  # free-running: a frame is always on its way
        if fake.queue:
            frame = fake.queue.pop(0)
            fake.keep.append(frame)  # out[0] stores only the address: keep the struct alive
            out[0] = ctypes.pointer(frame)
        else:
            out[0] = ctypes.POINTER(dc.VideoFrame)()
        return 0

    def dc1394_capture_enqueue(self, cam: Any, frame: Any) -> int:
        self._log("dc1394_capture_enqueue", (cam,))
        return 0

    def dc1394_feature_get_absolute_value(self, cam: Any, feature: int, value: Any) -> int:
        value[0] = 0.008
        return 0

    def dc1394_error_get_string(self, code: int) -> bytes:
        return f"fake dc1394 error {code}".encode()

    def pulse(self) -> int:
        """The trigger box: every armed, transmitting camera in trigger mode exposes one frame."""
        for fake in self.cams.values():
            if fake.trigger and fake.transmitting:
                fake.queue.append(fake.frame())
        return 1

    def of(self, guid: int, name: str) -> list[tuple[Any, ...]]:
        return [c[2:] for c in self.calls if c[0] == name and c[1] == guid]
