"""The libdc1394 backend: struct layout, missing library, and the call sequence against a fake lib."""

from __future__ import annotations

import ctypes
from typing import Any

import numpy as np
import pytest
from support.fake_dc1394 import GUID_A, GUID_B, FakeLib, pattern

from drivers.base import DeviceError
from drivers.stereo import BACKENDS, create
from drivers.stereo import dc1394_lib as dc
from drivers.stereo.dc1394 import Dc1394Cameras
from drivers.stereo.pair import StereoPair


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
