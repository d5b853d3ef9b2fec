"""The libdc1394 backend: struct layout, missing library, and the call sequence against a fake lib."""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np
import pytest

from drivers.base import DeviceError
from drivers.stereo import BACKENDS, create
from drivers.stereo import dc1394_lib as dc
from drivers.stereo.dc1394 import Dc1394Cameras
from drivers.stereo.pair import StereoPair

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


def make(lib: FakeLib, trigger: Any = "lib", **extra: Any) -> StereoPair:
    config = BACKENDS.settings(
        {"backend": "dc1394", "trigger_timeout": 0.2, "direct_timeout": 0.2, "resolution": "high", **extra})
    pair = StereoPair(config, Dc1394Cameras(config, lib=lib), lib.pulse if trigger == "lib" else trigger)
    pair.open()
    return pair


def test_struct_layout_matches_libdc1394_2_2() -> None:
    # Offsets printed by a C program against libdc1394 2.2.6 headers (x86-64).
    assert ctypes.sizeof(dc.VideoFrame) == 120
    assert dc.VideoFrame.size.offset == 8
    assert dc.VideoFrame.color_coding.offset == 24
    assert dc.VideoFrame.stride.offset == 40
    assert dc.VideoFrame.total_bytes.offset == 48
    assert dc.VideoFrame.image_bytes.offset == 56
    assert dc.VideoFrame.timestamp.offset == 72
    assert dc.VideoFrame.camera.offset == 88
    assert dc.VideoFrame.data_in_padding.offset == 116
    assert ctypes.sizeof(dc.CameraId) == 16 and ctypes.sizeof(dc.CameraList) == 16
    assert dc.Camera.vendor.offset == 144 and dc.Camera.model.offset == 152


def test_missing_library_says_how_to_install_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(dc.ctypes.util, "find_library", lambda name: None)
    cam = create({"backend": "dc1394", "library": "libdc1394-rvs-absent.so.99"})
    with pytest.raises(DeviceError) as info:
        cam.open()
    assert info.value.device == "stereo"
    assert "libdc1394 not found" in info.value.message
    assert "apt install libdc1394-25" in info.value.message
    assert "drivers.stereo.library" in info.value.message
    assert "libdc1394-rvs-absent.so.99" in info.value.message
    assert cam.status()["open"] is False


def test_no_cameras_names_the_wanted_ids() -> None:
    with pytest.raises(DeviceError) as info:
        make(FakeLib(guids=()), left_id="000a47010e0a0001", right_id="000a47010e0a0002")
    assert "no FireWire cameras found" in info.value.message
    assert "wanted left 000a47010e0a0001, right 000a47010e0a0002" in info.value.message


def test_unknown_guid_lists_what_was_found() -> None:
    with pytest.raises(DeviceError) as info:
        make(FakeLib(), left_id="000a4701deadbeef", right_id="1")
    assert "000a4701deadbeef" in info.value.message and f"{GUID_A:016x}" in info.value.message


def test_stereo_grab_configures_format7_external_trigger_and_copies_strided_frames() -> None:
    lib = FakeLib()
    cam = make(lib)
    assert cam.camera_ids() == {"left": f"{GUID_A:016x}", "right": f"{GUID_B:016x}"}
    left, right = cam.grab_stereo()
    assert left.shape == (960, 1280) and right.shape == (960, 1280)
    assert np.array_equal(left, pattern(40, 1280, 960, 1))  # padding bytes cropped, rows aligned
    assert np.array_equal(right, pattern(80, 1280, 960, 1))
    for guid in (GUID_A, GUID_B):
        names = [c[0] for c in lib.calls if len(c) > 1 and c[1] == guid]
        order = [
            "dc1394_video_set_operation_mode",
            "dc1394_video_set_iso_speed",
            "dc1394_video_set_mode",
            "dc1394_format7_set_roi",
            "dc1394_external_trigger_set_mode",
            "dc1394_external_trigger_set_power",
            "dc1394_capture_setup",
            "dc1394_video_set_transmission",
        ]
        positions = [names.index(n) for n in order]
        assert positions == sorted(positions), names
        assert lib.of(guid, "dc1394_video_set_mode") == [(dc.DC1394_VIDEO_MODE_FORMAT7_0,)]
        assert lib.of(guid, "dc1394_format7_set_roi") == [
            (dc.DC1394_VIDEO_MODE_FORMAT7_0, dc.DC1394_COLOR_CODING_MONO8, dc.DC1394_USE_MAX_AVAIL, 320, 56, 1280, 960)
        ]
        assert lib.of(guid, "dc1394_external_trigger_set_mode") == [(dc.DC1394_TRIGGER_MODE_0,)]
        assert lib.of(guid, "dc1394_external_trigger_set_power") == [(dc.DC1394_ON,)]
        assert lib.of(guid, "dc1394_capture_setup") == [(4, dc.DC1394_CAPTURE_FLAGS_DEFAULT)]
    # A second grab in the same mode reuses the running capture.
    cam.grab_stereo()
    assert len(lib.of(GUID_A, "dc1394_capture_setup")) == 1


def test_mode_change_restarts_capture_and_rgb8_has_three_channels() -> None:
    lib = FakeLib()
    cam = make(lib)
    cam.grab_stereo()
    left, _ = cam.grab_stereo(resolution="low", pixel_format="rgb8")
    assert left.shape == (480, 640, 3)
    assert np.array_equal(left, pattern(40, 640, 480, 3))
    assert lib.of(GUID_A, "dc1394_capture_stop") == [()]
    assert lib.of(GUID_A, "dc1394_format7_set_roi")[-1] == (
        dc.DC1394_VIDEO_MODE_FORMAT7_0, dc.DC1394_COLOR_CODING_RGB8, dc.DC1394_USE_MAX_AVAIL, 640, 296, 640, 480
    )  # fmt: skip


def test_missed_trigger_names_the_camera() -> None:
    lib = FakeLib()
    cam = make(lib, trigger=lambda: 1)  # a box that never reaches the cameras
    with pytest.raises(DeviceError) as info:
        cam.grab_stereo()
    assert f"camera {GUID_A:016x} (left) missed its trigger" in info.value.message
    assert f"{GUID_B:016x} (right)" in info.value.message


def test_stale_frames_are_flushed_before_a_triggered_grab() -> None:
    lib = FakeLib()
    cam = make(lib, trigger=lambda: 1)
    lib.pulse()  # nothing armed yet: no frames
    with pytest.raises(DeviceError):
        cam.grab_stereo()  # configures; the deaf trigger gives no new frame
    lib.pulse()  # a stray pulse after the failed grab leaves an old frame in the ring
    with pytest.raises(DeviceError, match="missed its trigger"):
        cam.grab_stereo()  # the old frame is flushed, not returned as this grab's image


def test_direct_grab_turns_the_trigger_off_and_fires_nothing() -> None:
    lib = FakeLib()
    fired: list[int] = []
    cam = make(lib, trigger=lambda: fired.append(1))
    left, right = cam.grab_stereo_direct(resolution="low")
    assert left.shape == (480, 640) and not fired
    assert lib.of(GUID_A, "dc1394_external_trigger_set_power") == [(dc.DC1394_OFF,)]
    assert cam.status()["left"]["trigger_mode"] == "free"
    mono = cam.grab_mono_direct("right", resolution="low")
    assert np.array_equal(mono, right)


def test_settings_are_written_through_absolute_features() -> None:
    lib = FakeLib()
    cam = make(lib)
    cam.set_settings("left", shutter_us=4000, gain_db=6.0, white_balance=(300, 700), target_grey=90)
    set_abs = lib.of(GUID_A, "dc1394_feature_set_absolute_value")
    assert set_abs[-2][0] == dc.DC1394_FEATURE_SHUTTER and set_abs[-2][1] == pytest.approx(0.004)
    assert set_abs[-1] == (dc.DC1394_FEATURE_GAIN, 6.0)
    assert lib.of(GUID_A, "dc1394_feature_whitebalance_set_value")[-1] == (300, 700)
    assert lib.of(GUID_A, "dc1394_feature_set_value")[-1] == (dc.DC1394_FEATURE_EXPOSURE, 90)
    cam.set_settings("right", auto_exposure=True)
    assert (dc.DC1394_FEATURE_SHUTTER, dc.DC1394_FEATURE_MODE_AUTO) in lib.of(GUID_B, "dc1394_feature_set_mode")


def test_failing_calls_become_device_errors_with_the_library_message() -> None:
    lib = FakeLib()
    cam = make(lib)
    lib.fail["dc1394_feature_set_absolute_value"] = -16
    with pytest.raises(DeviceError, match="fake dc1394 error -16"):
        cam.set_settings("left", gain_db=3.0)
    del lib.fail["dc1394_feature_set_absolute_value"]
    lib.fail["dc1394_capture_dequeue"] = -9
    with pytest.raises(DeviceError) as info:
        cam.grab_stereo()
    assert f"camera {GUID_A:016x} (left) is not answering" in info.value.message


def test_check_reset_and_close_release_everything() -> None:
    lib = FakeLib()
    cam = make(lib)
    assert cam.check()["check"]["left"]["shutter_us"] == 8000
    assert cam.check()["check"]["left"]["model"] == "PIKE F-210B"
    cam.grab_stereo()
    cam._backend.reset_settle_s = 0
    cam.reset()
    assert lib.of(GUID_A, "dc1394_camera_reset") == [()] and lib.of(GUID_B, "dc1394_camera_reset") == [()]
    assert cam.grab_stereo()[0].shape == (960, 1280)  # reconfigured after the reset
    cam.close()
    assert sorted(set(lib.freed)) == [GUID_A, GUID_B]
    assert lib.calls[-1] == ("dc1394_free",)
    assert cam.status()["open"] is False
