"""The simulated PIKE pair: geometry, trigger timing, exposure, formats, settings, ids, faults."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from support.stereo_fakeworld import FakeWorld

from drivers.base import DeviceError
from drivers.stereo import BACKENDS, GrabCancelled, StereoPair, create
from drivers.trigger import create as create_trigger

BASE = {
    "backend": "sim",
    "resolution": "low",
    "pixel_format": "mono8",
    "trigger_timeout": 0.3,
    "seed": 7,
}


def make(world: Any = None, trigger: bool = True, **extra: Any) -> tuple[StereoPair, Any, Any]:
    world = world if world is not None else FakeWorld()
    box = None
    if trigger:
        box = create_trigger({"backend": "sim", "pulse_us": 100}, world)
        box.open()
    cam = create({**BASE, **extra}, world, box)
    cam.open()
    return cam, box, world


def rectified_disparity(left: np.ndarray, right: np.ndarray, calib: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """SGBM disparity of the pair rectified with its own calibration; (disparity px, P1)."""
    size = tuple(calib["image_size"])
    R1, R2, P1, P2, _, _, _ = cv2.stereoRectify(
        calib["K1"], calib["D1"], calib["K2"], calib["D2"], size, calib["R"], np.reshape(calib["T"], (3, 1)), alpha=0
    )
    m1 = cv2.initUndistortRectifyMap(calib["K1"], calib["D1"], R1, P1, size, cv2.CV_32FC1)
    m2 = cv2.initUndistortRectifyMap(calib["K2"], calib["D2"], R2, P2, size, cv2.CV_32FC1)
    rl = cv2.remap(left, m1[0], m1[1], cv2.INTER_LINEAR)
    rr = cv2.remap(right, m2[0], m2[1], cv2.INTER_LINEAR)
    sgbm = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=96, blockSize=5, P1=8 * 25, P2=32 * 25, uniquenessRatio=10
    )
    disp = sgbm.compute(rl, rr).astype(np.float32) / 16.0
    disp[disp <= 0] = np.nan
    return disp, P1


def centre(a: np.ndarray, frac: float = 0.25) -> np.ndarray:
    h, w = a.shape[:2]
    return a[int(h * (0.5 - frac)) : int(h * (0.5 + frac)), int(w * (0.5 - frac)) : int(w * (0.5 + frac))]


# -- geometry ------------------------------------------------------------------------------------------
def test_disparity_equals_f_b_over_z_after_rectifying_with_the_calibration() -> None:
    cam, _, world = make()
    left, right = cam.grab_stereo()
    calib = cam.calibration()
    assert calib["image_size"] == [640, 480]
    assert np.linalg.norm(calib["T"]) == pytest.approx(world.head.baseline)
    assert np.any(calib["D1"] != 0)  # the images really are distorted
    disp, P1 = rectified_disparity(left, right, calib)
    expected = P1[0, 0] * world.head.baseline / world.wall_x
    measured = np.nanmedian(centre(disp))
    assert np.isfinite(centre(disp)).mean() > 0.8
    assert abs(measured - expected) < 1.0, (measured, expected)


def test_unrectified_distorted_pair_is_not_a_pure_shift() -> None:
    # Guard for the test above: without undistortion the same wall shows a disparity that varies
    # across the image, so the 1-pixel agreement above depends on applying the lens model.
    cam, _, _ = make(sim_distortion=[-0.25, 0.05, 0, 0, 0])
    left, right = cam.grab_stereo()
    calib = cam.calibration()
    ident = {**calib, "D1": np.zeros(5), "D2": np.zeros(5)}
    disp_raw, _ = rectified_disparity(left, right, ident)
    disp, _ = rectified_disparity(left, right, calib)
    h, w = disp.shape
    band = slice(h // 2 - 10, h // 2 + 10)
    spread_raw = np.nanmedian(disp_raw[band, 100:140]) - np.nanmedian(disp_raw[band, w // 2 - 20 : w // 2 + 20])
    spread = np.nanmedian(disp[band, 100:140]) - np.nanmedian(disp[band, w // 2 - 20 : w // 2 + 20])
    assert abs(spread) < 0.5
    assert abs(spread_raw) > 1.0


def test_rover_moved_between_pulses_changes_both_images_consistently() -> None:
    cam, box, world = make(sim_noise=False)
    before = cam.grab_stereo()
    world.move_rover(0.5, 0.0, 0.0)
    after = cam.grab_stereo()
    assert not np.array_equal(before[0], after[0]) and not np.array_equal(before[1], after[1])
    disp, P1 = rectified_disparity(after[0], after[1], cam.calibration())
    expected = P1[0, 0] * world.head.baseline / (world.wall_x - 0.5)
    assert abs(np.nanmedian(centre(disp)) - expected) < 1.0
    assert cam.last_grab()["pulse"] == box.count == world.trigger.count == 2


class MovingWorld(FakeWorld):
    """Moves the rover the first time a camera pose is read after each pulse: a pose snapshot taken
    camera by camera would put left and right at different instants."""

    def __init__(self) -> None:
        super().__init__()
        self.moved_at_pulse = -1

    def sensor_pose(self, sensor: str) -> np.ndarray:
        if self.trigger.count > 0 and self.moved_at_pulse != self.trigger.count:
            pose = super().sensor_pose(sensor)
            self.moved_at_pulse = self.trigger.count
            self.move_rover(0.3, 0.0, 0.0)
            return pose
        return super().sensor_pose(sensor)


def test_both_images_come_from_one_pose_snapshot() -> None:
    world = MovingWorld()
    cam, _, _ = make(world, sim_noise=False)
    left, right = cam.grab_stereo()
    disp, P1 = rectified_disparity(left, right, cam.calibration())
    expected = P1[0, 0] * world.head.baseline / (world.wall_x - 0.3)  # both after the move
    assert abs(np.nanmedian(centre(disp)) - expected) < 1.0


def test_grab_waits_for_a_pulse_fired_by_someone_else() -> None:
    # (the timeouts are safety nets: a pair takes ~2 s to render here, longer on a busy machine)
    cam, box, world = make(trigger=False, trigger_timeout=60.0)
    result: dict[str, Any] = {}

    def grab() -> None:
        result["pair"] = cam.grab_stereo(fire=False)

    worker = threading.Thread(target=grab)
    worker.start()
    deadline = time.monotonic() + 60
    while not cam.status()["busy"] and time.monotonic() < deadline:
        time.sleep(0.01)
    assert cam.status()["left"]["state"] == "busy"  # status answers while the grab waits
    world.move_rover(0.5, 0.0, 0.0)
    world.trigger.pulse()
    worker.join(120)
    left, right = result["pair"]
    disp, P1 = rectified_disparity(left, right, cam.calibration())
    assert abs(np.nanmedian(centre(disp)) - P1[0, 0] * 0.2 / 2.5) < 1.0
    assert cam.status()["busy"] is False


# -- trigger faults --------------------------------------------------------------------------------------
def test_missing_trigger_is_a_device_error_naming_the_camera() -> None:
    cam, box, world = make()
    left_id = cam.camera_ids()["left"]
    cam.inject_fault("no_trigger")
    with pytest.raises(DeviceError) as info:
        cam.grab_stereo()
    assert info.value.device == "stereo"
    assert f"camera {left_id} (left) missed its trigger" in info.value.message
    assert "within 0.308 s" in info.value.message  # trigger_timeout + the 8 ms exposure
    status = cam.status()
    assert status["left"]["state"] == "error" and status["right"]["state"] == "error"
    assert status["last_error"] == info.value.message
    assert world.trigger.count == 1  # the box did fire
    cam.inject_fault(None)
    left, right = cam.grab_stereo()
    assert left.shape == (480, 640)
    assert cam.status()["left"]["state"] == "idle"


def test_one_deaf_camera_is_named() -> None:
    cam, _, _ = make()
    right_id = cam.camera_ids()["right"]
    cam.inject_fault("no_trigger", "right")
    with pytest.raises(DeviceError, match=f"camera {right_id} \\(right\\) missed its trigger"):
        cam.grab_stereo()
    assert cam.grab_left().shape == (480, 640)  # the left camera still works


def test_no_pulse_at_all_times_out() -> None:
    cam, _, _ = make(trigger=False)
    with pytest.raises(DeviceError, match="missed its trigger"):
        cam.grab_stereo(fire=False)
    with pytest.raises(DeviceError, match="no trigger box attached"):
        cam.grab_stereo()
    assert cam.grab_stereo_direct()[0].shape == (480, 640)  # free-running needs no trigger


def test_trigger_box_failure_propagates_as_the_trigger_error() -> None:
    cam, box, _ = make()
    box.inject_fault("busy")
    with pytest.raises(DeviceError) as info:
        cam.grab_stereo()
    assert info.value.device == "trigger" and "rmmod lp" in info.value.message
    assert cam.status()["left"]["state"] == "error"


def test_cancel_interrupts_the_wait() -> None:
    cam, _, _ = make(trigger=False, trigger_timeout=30.0)
    stop = threading.Event()
    threading.Timer(0.1, stop.set).start()
    with pytest.raises(GrabCancelled):
        cam.grab_stereo(fire=False, cancel=stop)
    assert cam.status()["left"]["state"] == "idle"


def test_unplugged_camera_needs_a_reinit_after_replugging() -> None:
    cam, _, _ = make()
    left_id = cam.camera_ids()["left"]
    cam.inject_fault("unplug", "left")
    with pytest.raises(DeviceError) as info:
        cam.grab_stereo()
    assert info.value.device == "stereo" and f"camera {left_id} (left)" in info.value.message
    with pytest.raises(DeviceError):
        cam.check()
    with pytest.raises(DeviceError, match="not found|only 1 found"):
        cam.reinit()  # still unplugged: the bus has one camera
    cam.inject_fault(None)
    with pytest.raises(DeviceError, match="not initialised"):
        cam.grab_stereo()  # the failed reinit left the pair closed
    cam.reinit()
    assert cam.check()["check"]["left"]["responding"] is True
    assert cam.grab_stereo()[0].shape == (480, 640)


# -- exposure ------------------------------------------------------------------------------------------
def mean_of(cam: StereoPair, **settings: Any) -> tuple[float, int]:
    cam.set_settings("both", **settings)
    img = cam.grab_left()
    return float(img.mean()), int(img.max())


def test_shutter_and_gain_raise_brightness_monotonically_until_saturation() -> None:
    cam, _, _ = make(sim_noise=False)
    shutters = [500, 1000, 2000, 4000, 8000, 16000, 64000, 1_000_000]
    means = [mean_of(cam, shutter_us=s, gain_db=0)[0] for s in shutters]
    assert all(b > a for a, b in zip(means[:5], means[1:6], strict=True)), means
    assert means[3] == pytest.approx(2 * means[2], rel=0.05)  # linear below saturation
    top, peak = mean_of(cam, shutter_us=1_000_000)
    assert top == 255.0 and peak == 255  # saturated, never wraps
    gains = [0.0, 6.0, 12.0, 22.0]
    g_means = [mean_of(cam, shutter_us=2000, gain_db=g)[0] for g in gains]
    assert all(b > a for a, b in zip(g_means, g_means[1:], strict=False)), g_means
    assert g_means[1] == pytest.approx(g_means[0] * 10 ** (6 / 20), rel=0.05)
    assert mean_of(cam, shutter_us=60000, gain_db=22)[0] == 255.0


def test_noise_is_seeded_and_matches_shot_plus_read_noise() -> None:
    a, _, _ = make(seed=5)
    b, _, _ = make(seed=5)
    c, _, _ = make(seed=6)
    quiet, _, _ = make(sim_noise=False)
    la, lb, lc, lq = a.grab_left(), b.grab_left(), c.grab_left(), quiet.grab_left()
    assert np.array_equal(la, lb)
    assert not np.array_equal(la, lc)
    diff = la.astype(np.float64) - lq
    mean_dn = lq.mean()
    # 20000 e- full well = 255 DN: shot noise sqrt(e) plus 12 e- read noise, plus quantisation.
    electrons = mean_dn / 255 * 20000
    expected = np.sqrt(electrons + 144) * 255 / 20000
    assert diff.std() == pytest.approx(np.sqrt(expected**2 + 1 / 12), rel=0.15)


def test_auto_exposure_reaches_the_target_grey() -> None:
    cam, _, _ = make(sim_noise=False)
    cam.set_settings("both", auto_exposure=True, target_grey=100)
    left = cam.grab_left()
    assert left.mean() == pytest.approx(100, abs=3)
    assert cam.last_grab()["effective_shutter_us"]["left"] != 8000


# -- formats and modes ---------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("resolution", "shape"),
    [("low", (480, 640)), ("medium", (768, 1024)), ("high", (960, 1280)), ("highest", (1080, 1920))],
)
def test_resolution_modes(resolution: str, shape: tuple[int, int]) -> None:
    cam, _, _ = make()
    left, right = cam.grab_stereo(resolution=resolution)
    assert left.shape == shape and right.shape == shape
    assert left.dtype == np.uint8
    assert cam.calibration(resolution)["image_size"] == [shape[1], shape[0]]


def test_rgb8_has_three_channels_and_follows_white_balance() -> None:
    cam, _, _ = make(sim_noise=False)
    mono = cam.grab_left()
    rgb = cam.grab_left(pixel_format="rgb8")
    assert mono.shape == (480, 640) and rgb.shape == (480, 640, 3)
    assert np.abs(rgb[..., 1].astype(int) - mono).max() <= 1  # unity white balance: G equals mono
    cam.set_settings("left", white_balance=(256, 768))
    tinted = cam.grab_left(pixel_format="rgb8").astype(float)
    assert tinted[..., 0].mean() == pytest.approx(1.5 * rgb[..., 0].mean(), rel=0.03)  # V/R 768/512
    assert tinted[..., 2].mean() == pytest.approx(0.5 * rgb[..., 2].mean(), rel=0.03)  # U/B 256/512


@pytest.mark.parametrize("bad", ["yuv422", "mono16", "RGB24", ""])
def test_invalid_pixel_format_is_a_usage_error(bad: str) -> None:
    cam, _, world = make()
    with pytest.raises(ValueError, match="accepted: mono8, rgb8"):
        cam.grab_stereo(pixel_format=bad or "raw")
    with pytest.raises(ValueError, match="accepted: mono8, rgb8"):
        cam.set_mode(pixel_format=bad or "raw")
    assert world.trigger.count == 0  # rejected before anything was fired


def test_invalid_resolution_lists_the_modes() -> None:
    cam, _, _ = make()
    with pytest.raises(ValueError, match="low 640x480, medium 1024x768, high 1280x960, highest 1920x1080"):
        cam.grab_left(resolution="ultra")


# -- settings --------------------------------------------------------------------------------------------
def test_settings_save_load_round_trip(tmp_path: Path) -> None:
    cam, _, _ = make()
    cam.set_settings("left", shutter_us=1234, gain_db=3.5, target_grey=90)
    cam.set_settings("right", white_balance=(600, 400), auto_exposure=True)
    path = cam.save_settings(tmp_path / "cams.yaml")
    doc = yaml.safe_load(path.read_text())
    assert doc["left"]["target_grey"] == 90  # the value the UniAPI forgot to store
    saved = cam.get_settings()
    other, _, _ = make()
    assert other.get_settings() != saved
    assert other.load_settings(path) == saved
    assert other.status()["right"]["settings"]["auto_exposure"] is True


def test_partial_and_bad_settings_files(tmp_path: Path) -> None:
    cam, _, _ = make()
    (tmp_path / "part.yaml").write_text("left: {gain_db: 6}\n")
    loaded = cam.load_settings(tmp_path / "part.yaml")
    assert loaded["left"]["gain_db"] == 6.0 and loaded["left"]["shutter_us"] == 8000
    (tmp_path / "bad.yaml").write_text("left: {shutter_us: -5}\n")
    with pytest.raises(ValueError, match="shutter_us"):
        cam.load_settings(tmp_path / "bad.yaml")
    with pytest.raises(ValueError, match="does not exist"):
        cam.load_settings(tmp_path / "none.yaml")
    with pytest.raises(ValueError, match="accepted: shutter_us"):
        cam.set_settings("left", exposure=3)
    with pytest.raises(ValueError, match="gain_db"):
        cam.set_settings("both", gain_db=40)
    assert cam.get_settings("left")["gain_db"] == 6.0  # a rejected change leaves settings alone


def test_reinit_restores_the_default_settings() -> None:
    cam, _, _ = make(shutter_us=5000)
    cam.set_settings("both", shutter_us=100)
    cam.reinit()
    assert cam.get_settings("left")["shutter_us"] == 5000
    cam.set_settings("right", gain_db=10)
    cam.reset()
    assert cam.get_settings("right")["gain_db"] == 0.0


# -- camera ids --------------------------------------------------------------------------------------------
def test_swapping_ids_swaps_the_images() -> None:
    cam, _, _ = make(sim_noise=False)
    ids = cam.camera_ids()
    left, right = cam.grab_stereo()
    assert not np.array_equal(left, right)
    assert cam.swap_camera_ids() == {"left": ids["right"], "right": ids["left"]}
    left2, right2 = cam.grab_stereo()
    assert np.array_equal(left2, right) and np.array_equal(right2, left)
    assert cam.calibration()["T"][0] == pytest.approx(0.2)  # the "left" camera now sits on the right


def test_set_ids_by_guid_and_index_and_unknown_ids() -> None:
    cam, _, _ = make()
    found = cam.available_ids()
    assert len(found) == 2
    assert cam.set_camera_ids(found[1], found[0]) == {"left": found[1], "right": found[0]}
    assert cam.set_camera_ids("0", "1") == {"left": found[0], "right": found[1]}
    with pytest.raises(DeviceError) as info:
        cam.set_camera_ids("deadbeef", "1")
    assert "deadbeef" in info.value.message and found[0] in info.value.message
    with pytest.raises(ValueError, match="different cameras"):
        cam.set_camera_ids("0", "0")


def test_configured_ids_that_are_absent_fail_at_open() -> None:
    world = FakeWorld()
    cam = create({**BASE, "left_id": "0", "right_id": "5"}, world)
    with pytest.raises(DeviceError) as info:
        cam.open()
    assert "camera #5" in info.value.message and "wanted left 0, right 5" in info.value.message
    assert cam.status()["open"] is False


def test_status_is_readable_from_other_threads_during_grabs() -> None:
    cam, _, _ = make()
    errors: list[BaseException] = []
    done = threading.Event()

    def poll() -> None:
        try:
            while not done.is_set():
                snap = cam.status()
                assert snap["left"]["state"] in ("idle", "busy")
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    poller = threading.Thread(target=poll)
    poller.start()
    for _ in range(3):
        cam.grab_stereo()
    done.set()
    poller.join()
    assert not errors
    assert cam.status()["grabs"] == 3 and cam.status()["left"]["frames"] == 3


def test_unknown_backend_and_fault() -> None:
    with pytest.raises(ValueError, match="unknown backend 'gige'.*registered: " + ", ".join(BACKENDS.names())):
        create({"backend": "gige"})
    cam, _, _ = make()
    with pytest.raises(ValueError, match="no_trigger, unplug"):
        cam.inject_fault("melt")


# -- the shared simulated world ---------------------------------------------------------------------------
def test_office_scene_pair_matches_the_true_depth() -> None:
    from drivers.sim.world import World

    world = World.from_scene("office", seed=0)
    cam, box, _ = make(world, trigger_timeout=5.0)
    left, right = cam.grab_stereo()
    assert box.count == 1 and world.trigger.count == 1
    calib = cam.calibration()
    disp, P1 = rectified_disparity(left, right, calib)
    size = tuple(calib["image_size"])
    R1 = cv2.stereoRectify(
        calib["K1"], calib["D1"], calib["K2"], calib["D2"], size, calib["R"], np.reshape(calib["T"], (3, 1)), alpha=0
    )[0]
    T_world_rect = world.sensor_pose("left").copy()
    T_world_rect[:3, :3] = T_world_rect[:3, :3] @ R1.T  # the rectified left camera
    truth = world.render(P1[:3, :3], size[0], size[1], T_world_rect)
    expected = P1[0, 0] * np.linalg.norm(calib["T"]) / truth.depth
    ok = np.isfinite(disp) & np.isfinite(expected)
    assert ok.mean() > 0.2
    error = np.abs(disp[ok] - expected[ok])
    assert np.median(error) < 1.0, np.median(error)


def test_the_shipped_drivers_yaml_section_builds_a_working_pair() -> None:
    config = yaml.safe_load((Path(__file__).parents[2] / "config" / "drivers.yaml").read_text())
    world = FakeWorld()
    box = create_trigger(config["trigger"], world)
    box.open()
    cam = create({**config["stereo"], "resolution": "low"}, world, box)
    cam.open()
    left, right = cam.grab_stereo()
    assert left.shape == (480, 640) and cam.status()["backend"] == "sim"
    assert cam.get_settings("left")["white_balance"] == [512, 512]
