"""The simulated SR4000 through the Tof device: noise model, wrap, confidence, artefacts, faults."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
from tof_rig import Plane, PlaneWorld, floor_world, look_at, open_camera, wall_world

from drivers.base import Device, DeviceError
from drivers.tof import Cancelled
from drivers.tof import constants as k
from drivers.tof.physics import SignalModel


def truth(world, cam):
    K, _ = cam.intrinsics()
    return world.render(K, k.WIDTH, k.HEIGHT, world.sensor_pose("tof"))


def normalised_error(cam, world, integrate):
    """(measured - true range) / model sigma per pixel, for one grab of ``integrate`` frames."""
    r = truth(world, cam)
    d = cam.grab("distance", integrate, undistort=False)
    amp = SignalModel().amplitude(r.albedo, r.cos_incidence, r.range, k.integration_ms(30))
    sigma = cam._cam.model.range_sigma(amp, 30.0)
    return (d - r.range) / sigma


def test_flat_floor_at_1_5_m_mean_z_error_and_noise_match_the_model():
    world = floor_world(1.5, albedo=0.5)
    cam = open_camera(world)
    assert isinstance(cam, Device)
    r = truth(world, cam)
    xyz, amplitude = cam.grab_xyz(integrate=30)
    z_err = xyz[..., 2] - r.depth
    assert (xyz != -1).all()
    assert abs(float(z_err.mean())) < 0.005

    # Per-pixel scatter over single frames against sigma = sqrt(floor^2 + (k/A)^2).
    frames = np.stack([cam.grab("distance", 1, undistort=False) for _ in range(30)])
    measured = frames.std(axis=0, ddof=1)
    predicted = cam._cam.model.range_sigma(amplitude, 30.0)
    pooled = math.sqrt(float(np.mean(measured**2)) / float(np.mean(predicted**2)))
    assert 0.8 < pooled < 1.2
    assert 0.9 < float(np.median(measured / predicted)) < 1.1
    centre = measured[62:82, 78:98].mean()
    assert 0.005 < centre < 0.007  # 6 mm for albedo 0.5 straight ahead at 3.3 ms, as documented


def test_integrating_n_frames_divides_the_noise_by_sqrt_n():
    world = floor_world(1.5)
    cam = open_camera(world)
    single = float(np.std(normalised_error(cam, world, 1)))
    sixteen = float(np.std(normalised_error(cam, world, 16)))
    assert 0.85 < single < 1.15
    assert 0.8 < (single / sixteen) / 4.0 < 1.2


def test_noise_grows_as_amplitude_falls():
    near = open_camera(wall_world(1.0))
    far = open_camera(wall_world(3.0))
    s_near = np.std(np.stack([near.grab("distance", undistort=False) for _ in range(8)]), axis=0).mean()
    s_far = np.std(np.stack([far.grab("distance", undistort=False) for _ in range(8)]), axis=0).mean()
    # amplitude ~ 1/r^2 and sigma ~ 1/amplitude: nine times the amplitude ratio, minus the floor.
    assert s_far / s_near > 5.0


def test_range_wraps_at_c_over_2f_and_a_longer_range_frequency_unwraps_it():
    world = wall_world(7.0)
    cam = open_camera(world, integration=255)
    r = truth(world, cam)
    centre = (slice(62, 82), slice(78, 98))
    d = cam.grab("distance", 10, undistort=False)
    expected = r.range[centre] - k.unambiguous_range(30.0)
    assert np.median(np.abs(d[centre] - expected)) < 0.02
    assert float(np.nanmax(d)) < k.unambiguous_range(30.0)

    assert cam.set_max_distance(8.0) == 15.0
    assert cam.status()["range_max_m"] == pytest.approx(9.9931, abs=1e-3)
    d15 = cam.grab("distance", 10, undistort=False)
    assert np.median(np.abs(d15[centre] - r.range[centre])) < 0.03


def test_confidence_threshold_discards_low_amplitude_pixels():
    # A dark floor with a bright mat on its left half, 1.5 m below the camera.
    planes = [
        Plane((0, 0, 0), (0, 0, 1), albedo=0.05),
        Plane((0, 1.0, 0.001), (0, 0, 1), albedo=0.8, u=(1, 0, 0), v=(0, 1, 0), half_u=5, half_v=1.0),
    ]
    world = PlaneWorld(planes, look_at((0, 0, 1.5), (0, 0, 0), up=(1, 0, 0)))
    cam = open_camera(world)
    bright = truth(world, cam).object_id == 1
    assert 0.3 < bright.mean() < 0.7

    xyz, _ = cam.grab_xyz(integrate=4, confidence=0.9)
    undefined = (xyz == -1).all(axis=-1)
    assert undefined[~bright].mean() > 0.99
    assert not undefined[bright].any()
    d = cam.grab("distance", 4, confidence=0.9, undistort=False)
    assert np.isnan(d[~bright]).mean() > 0.99 and np.isfinite(d[bright]).all()

    xyz_all, _ = cam.grab_xyz(integrate=4, confidence=0.0)
    assert not (xyz_all == -1).all(axis=-1).any()
    conf = cam.grab("confidence", 2, undistort=False)
    assert conf[bright].min() > 0.9 > conf[~bright].max()


def test_confidence_threshold_needs_the_confidence_map():
    cam = open_camera(floor_world(), corrections=["fix_pattern"])
    with pytest.raises(ValueError, match="conf_map"):
        cam.grab("distance", 1, confidence=0.5)
    assert np.isfinite(cam.grab("distance", 1)).all()


def test_saturation_at_close_range_with_long_integration():
    world = wall_world(0.5, albedo=0.8)
    cam = open_camera(world, integration=200)
    xyz, _ = cam.grab_xyz(2)
    assert (xyz == -1).all()  # saturated: confidence 0, never used
    assert np.isnan(cam.grab("distance", 2)).all()
    cam.set_integration(2)
    xyz, _ = cam.grab_xyz(2)
    assert not (xyz == -1).any()
    assert abs(float(np.median(xyz[..., 2])) - 0.5) < 0.01


def test_mixed_pixels_fly_between_foreground_and_background_at_depth_edges():
    # A dark board at 1 m, its edge tilted across the view, before a bright wall at 2 m: both
    # return about the same amplitude, so an edge pixel's phasor sum lands in between.
    tilt = math.radians(20)
    u = (0.0, math.cos(tilt), math.sin(tilt))
    v = (0.0, -math.sin(tilt), math.cos(tilt))
    board = Plane((1.0, 0.5, 1.0), (-1, 0, 0), 0.2, u=u, v=v, half_u=0.5, half_v=2.0)
    wall = Plane((2.0, 0, 0), (-1, 0, 0), 0.8)
    world = PlaneWorld([board, wall], look_at((0, 0, 1), (2.0, 0, 1)))

    def flying(**overrides):
        cam = open_camera(world, integration=60, **overrides)
        d = cam.grab("distance", 8, undistort=False)
        return int(((d > 1.15) & (d < 1.85)).sum())

    assert flying(sim_supersample=1) == 0
    assert flying() >= 40  # about one per image row along the edge


def test_multipath_makes_the_floor_near_a_wall_read_too_far():
    floor = Plane((0, 0, 0), (0, 0, 1), 0.45)
    wall = Plane((2.0, 0, 0), (-1, 0, 0), 0.85)
    world = PlaneWorld([floor, wall], look_at((0, 0, 1.2), (1.5, 0, 0)))
    r = truth(world, open_camera(world))
    on_floor = r.object_id == 0
    x = r.points[..., 0]
    near = on_floor & (x > 1.5) & (x < 1.9)
    far = on_floor & (x < 0.9)
    assert near.sum() > 200 and far.sum() > 200

    def bias(gain):
        cam = open_camera(world, sim_multipath_gain=gain)
        d = cam.grab("distance", 20, undistort=False)
        err = d - r.range
        return float(err[near].mean()), float(err[far].mean())

    near_bias, far_bias = bias(0.3)
    assert near_bias > 0.01  # centimetres too long next to the wall (seed 000 sect. 5.2.3)
    assert near_bias > 2 * abs(far_bias)
    assert abs(bias(0.0)[0]) < 0.003


def test_amplitude_follows_the_integration_register():
    cam = open_camera(wall_world(2.0))
    a30 = np.nanmedian(cam.grab("amplitude", 4, undistort=False))
    cam.set_integration(80)
    a80 = np.nanmedian(cam.grab("amplitude", 4, undistort=False))
    assert a80 / a30 == pytest.approx(k.integration_ms(80) / k.integration_ms(30), rel=0.03)
    plain = cam.grab("amplitude", 8, undistort=False)
    cam.set_correction_modes(conv_gray=True)  # times (range / 2 m)^2: unchanged at 2 m on axis
    grey = cam.grab("amplitude", 8, undistort=False)
    assert grey[72, 88] == pytest.approx(plain[72, 88], rel=0.03)
    assert grey[0, 0] / plain[0, 0] == pytest.approx(1.0 / np.prod(np.cos(np.radians([21.8, 17.3]))) ** 2, rel=0.05)


def test_amplitude_threshold_zeroes_weak_pixels():
    world = wall_world(2.0)
    cam = open_camera(world)
    level = float(np.nanmedian(cam.grab("amplitude", 2, undistort=False)))
    cam.set_amplitude_threshold(int(level * 2))
    assert np.isnan(cam.grab("distance", 2, undistort=False)).all()
    cam.set_amplitude_threshold(int(level / 2))
    assert np.isfinite(cam.grab("distance", 2, undistort=False)).all()


def test_auto_exposure_settles_before_the_grab_and_respects_its_cap():
    world = wall_world(1.5)
    cam = open_camera(world, integration=3, corrections=["fix_pattern", "conf_map"])
    cam.set_auto_exposure(True, 1, 250, 5, 70, max_iterations=40)
    before = cam.status()["frames"]
    amp = cam.grab("amplitude", 2, undistort=False)
    st = cam.status()
    assert st["exposure_mode"] == "auto" and st["exposure_settled"] is True
    assert st["frames"] - before == st["exposure_frames"] + 2
    assert st["integration"] > 30  # it started far too short
    # The 95th percentile sits near desired/255 of full scale.
    target = 70 / 255 * cam._cam.model.saturation
    assert np.nanpercentile(amp, 95) == pytest.approx(target, rel=0.15)

    cam.set_integration(0)
    cam.set_auto_exposure(True, max_iterations=2)
    before = cam.status()["frames"]
    cam.grab("distance", 1)
    st = cam.status()
    assert st["exposure_settled"] is False and st["exposure_frames"] == 2
    assert st["frames"] - before == 3


def test_unplug_fault_persists_until_cleared_then_reinit_reopens():
    cam = open_camera(floor_world())
    cam.inject_fault("unplug")
    with pytest.raises(DeviceError) as err:
        cam.grab("distance")
    assert err.value.device == "tof" and "disconnected (USB)" in str(err.value)
    st = cam.status()
    assert st["open"] is False and "disconnected" in st["last_error"] and st["fault"] == "unplug"
    for call in (cam.check, cam.reinit, lambda: cam.set_integration(20)):
        with pytest.raises(DeviceError, match="^tof: "):
            call()
    cam.inject_fault(None)
    with pytest.raises(DeviceError, match="not open"):
        cam.grab("distance")
    cam.reinit()
    assert cam.status()["open"] is True
    assert np.isfinite(cam.grab("distance")).all()


def test_unplugged_mid_stream_and_reset():
    cam = open_camera(floor_world())
    cam.inject_fault("unplug", after=3)
    frames = cam.status()["frames"]
    with pytest.raises(DeviceError, match="disconnected"):
        cam.grab("z", integrate=10)
    assert cam.status()["frames"] - frames == 3
    cam.inject_fault(None)
    cam.reset()
    assert cam.grab("z", 2).shape == (k.HEIGHT, k.WIDTH)


def test_timeout_fault_fails_acquisition_only():
    cam = open_camera(floor_world())
    cam.inject_fault("timeout")
    with pytest.raises(DeviceError, match="timed out") as err:
        cam.grab_xyz(1)
    assert err.value.device == "tof"
    cam.set_integration(40)  # the camera still answers register calls
    assert cam.check()["integration"] == 40
    cam.inject_fault(None)
    xyz, _ = cam.grab_xyz(1)
    assert (xyz[..., 2] > 1.4).all()
    with pytest.raises(ValueError, match="unknown ToF fault"):
        cam.inject_fault("melt")


def test_status_is_readable_from_another_thread_while_a_grab_holds_the_camera():
    cam = open_camera(floor_world())
    inside, release = threading.Event(), threading.Event()
    calls = []

    def gate():  # the cancel callable runs before every frame, inside the grab
        calls.append(1)
        if len(calls) == 2:
            inside.set()
            release.wait(10)
        return False

    result = {}
    worker = threading.Thread(target=lambda: result.setdefault("img", cam.grab("amplitude", 3, cancel=gate)))
    worker.start()
    assert inside.wait(10)
    st = cam.status()  # must not wait for the grab's lock
    assert st["busy"] is True and st["image_type"] == "amplitude"
    release.set()
    worker.join(10)
    assert result["img"].shape == (k.HEIGHT, k.WIDTH)
    assert cam.status()["busy"] is False


def test_cancel_event_stops_a_grab():
    cam = open_camera(floor_world())
    stop = threading.Event()
    stop.set()
    with pytest.raises(Cancelled):
        cam.grab("distance", 5, cancel=stop)
    assert cam.status()["busy"] is False
    with pytest.raises(ValueError, match="integrate"):
        cam.grab("distance", 0)
    with pytest.raises(ValueError, match="image type"):
        cam.grab("colour")


def test_undistortion_removes_the_lens_distortion_of_2d_images_only():
    # An oblique floor: range changes fast across the image, so misplaced pixels show.
    world = PlaneWorld([Plane((0, 0, 0), (0, 0, 1), 0.5)], look_at((0, 0, 1.2), (1.5, 0, 0)))
    cam = open_camera(world, integration=120, distortion=[-0.25, 0.05, 0.0, 0.0, 0.0])
    r = truth(world, cam)  # the ideal pinhole view
    inner = (slice(10, -10), slice(10, -10))  # undistortion leaves the border partly empty
    raw = cam.grab("distance", 16, undistort=False)
    fixed = cam.grab("distance", 16)
    assert np.nanpercentile(np.abs(raw - r.range), 95) > 0.03
    assert np.nanmedian(np.abs(fixed - r.range)[inner]) < 0.0015
    assert np.nanpercentile(np.abs(fixed - r.range)[inner], 95) < 0.005
    xyz, _ = cam.grab_xyz(16)  # the camera's coordinates are already correct: points on the floor
    points = xyz.reshape(-1, 3) @ world.T[:3, :3].T + world.T[:3, 3]
    assert np.median(np.abs(points[:, 2])) < 0.002


def test_correction_modes_map_to_acquire_mode_flags():
    cam = open_camera(floor_world())
    modes = cam.set_correction_modes(median=True, conv_gray=True)
    assert modes == {"fix_pattern": True, "median": True, "denoise_anf": False, "conv_gray": True, "conf_map": True}
    mode = cam.get_mode()
    for flag in (k.AcquireMode.AM_COR_FIX_PTRN, k.AcquireMode.AM_MEDIAN, k.AcquireMode.AM_CONV_GRAY, k.AcquireMode.AM_CONF_MAP):
        assert mode & flag
    assert not mode & k.AcquireMode.AM_DENOISE_ANF
    assert mode & k.AcquireMode.AM_SW_TRIGGER and cam.status()["trigger_mode"] == "software"
    cam.set_enhanced_xyz(True)
    assert cam.get_mode() & k.AcquireMode.AM_SHORT_RANGE and cam.status()["enhanced_xyz"] is True
    with pytest.raises(ValueError, match="unknown correction"):
        cam.set_correction_modes(sharpen=True)


def test_on_chip_filters_reduce_noise():
    world = floor_world(1.5)
    plain = float(np.std(normalised_error(open_camera(world), world, 1)))
    anf = float(np.std(normalised_error(open_camera(world, corrections=["fix_pattern", "denoise_anf"]), world, 1)))
    median = float(np.std(normalised_error(open_camera(world, corrections=["fix_pattern", "median"]), world, 1)))
    assert anf < 0.6 * plain and median < 0.8 * plain
    # Without fix-pattern correction every pixel keeps a constant offset: integration cannot remove it.
    no_fpn = open_camera(world, corrections=["conf_map"])
    assert float(np.std(normalised_error(no_fpn, world, 16))) > 1.0


def test_fake_colouring_uses_the_colour_range():
    cam = open_camera(floor_world())
    image = np.array([[0.0, 1.0, 2.0, np.nan]], dtype=np.float32)
    cam.set_colour_range(0.5, 1.5, "distance")
    bgr = cam.fake_colour(image, "distance")
    assert tuple(bgr[0, 0]) == (128, 0, 0)  # dark blue below the range
    assert tuple(bgr[0, 2]) == (0, 0, 128)  # dark red above it
    assert tuple(bgr[0, 3]) == (0, 0, 0)  # undefined
    grey = cam.fake_colour(image, "distance", mode="grey")
    assert grey[0, 1, 0] == 128 and grey[0, 0, 0] == 0 and grey[0, 2, 0] == 255
    cam.set_colour_range(None, None, "distance")
    assert cam.get_colour_range("distance") is None
    with pytest.raises(ValueError):
        cam.set_colour_range(2.0, 1.0, "distance")


def test_the_sim_camera_sees_the_office_world_from_the_ptu_pose():
    from drivers.sim.world import World

    world = World.from_scene("office", seed=0)
    cam = open_camera(world, sim_multipath_gain=0.3)
    # Tilted down so the floor at the image centre is about 1.5 m away.
    world.set_ptu(0.0, -55.0)
    r = world.render_sensor("tof", k.WIDTH, k.HEIGHT)
    assert 1.4 < r.range[72, 88] < 1.6
    xyz, amplitude = cam.grab_xyz(integrate=20)
    floor = (r.object_id == 0) & (r.normal[..., 2] > 0.999)
    z_err = (xyz[..., 2] - r.depth)[floor & (xyz[..., 2] > 0)]
    assert floor.mean() > 0.5 and abs(float(z_err.mean())) < 0.005

    # Noise at the image centre: about 1 cm there (the documented figure), as the model predicts.
    centre = (slice(62, 82), slice(78, 98))
    frames = np.stack([cam.grab("z", 1, undistort=False) for _ in range(20)])
    measured = float(frames.std(axis=0, ddof=1)[centre].mean())
    predicted = float(cam._cam.model.range_sigma(amplitude[centre], 30.0).mean())
    assert measured == pytest.approx(predicted, rel=0.2)
    assert 0.008 < measured < 0.012

    world.set_ptu(30.0, -10.0)  # the head moved: the camera sees something else
    xyz2, _ = cam.grab_xyz(1)
    assert np.nanmedian(np.abs(xyz2[..., 2] - xyz[..., 2])) > 0.1


def test_integrating_across_the_wrap_leaves_no_phantom_half_way() -> None:
    """A wall at the unambiguous range reads ~0 m in some frames and ~5 m in others; the
    integrated XYZ must not put it at ~2.5 m (the mean of the two)."""
    from drivers.sim.world import World
    from drivers.tof import create

    world = World.from_scene("office")
    world.set_rover_pose(0.34, 0.0, 0.0)  # the front wall (x = 5.5) ~5.0 m from the camera
    world.set_ptu(0.0, 0.0)
    cam = create({"backend": "sim", "seed": 3}, world)
    cam.open()
    xyz, _ = cam.grab_xyz(integrate=8)
    rng = np.linalg.norm(xyz, axis=2)
    defined = xyz[..., 2] > 0
    centre = np.zeros_like(defined)
    centre[50:94, 60:116] = True
    assert (defined & centre).sum() > 100
    assert not (defined & centre & (rng > 1.0) & (rng < 4.0)).any()


def test_the_wrap_check_drops_a_far_wall_read_close_by_and_keeps_every_true_return() -> None:
    """From the office's corner (the navigate corner missions' start) the top rows of a view see the front wall about
    7 m away; at 30 MHz it reads 2.2 m, phantoms above the floor that the amplitude filter keeps
    (a bright wall is as bright as a dark rock at grazing incidence). The frame at 15 MHz reads
    them at 7 m: the check drops them, and no pixel whose range is right."""
    from drivers.sim.world import World
    from drivers.tof import create

    world = World.from_scene("office")
    world.set_rover_pose(-1.52, -1.12, 20.0)
    world.set_ptu(14.4, -27.3)
    cam = create({"backend": "sim", "seed": 3}, world)
    cam.open()
    truth = world.render_sensor("tof", k.WIDTH, k.HEIGHT)
    counts = {}
    for check in (False, True):
        frames = cam.status()["frames"]
        xyz, _ = cam.grab_xyz(4, 0.3, wrap_check=check)
        counts[check, "frames"] = cam.status()["frames"] - frames
        defined = xyz[..., 2] > 0
        err = np.abs(np.linalg.norm(xyz, axis=2) - truth.range)
        counts[check, "wrapped"] = int((defined & (err > 1.0)).sum())
        counts[check, "right"] = int((defined & (err < 0.2)).sum())
        if not check:
            wrapped = defined & (err > 1.0)
            assert (truth.range[wrapped] > k.unambiguous_range(30.0) - 0.1).all()  # all of them beyond 5 m
    assert counts[False, "wrapped"] > 200  # the defect: phantoms from beyond the unambiguous range
    assert counts[True, "wrapped"] == 0
    assert counts[True, "right"] >= 0.99 * counts[False, "right"]
    assert counts[True, "frames"] == counts[False, "frames"] + 1  # one check frame
    assert cam.get_settings().modulation_mhz == 30.0 and cam._cam.get_modulation() == 30.0  # restored
