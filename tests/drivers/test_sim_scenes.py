"""Scene files: all load, are deterministic by seed, and hold what their description promises."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from drivers.sim.scene import load_scene_spec
from drivers.sim.terrain import golombek_counts
from drivers.sim.world import World


@pytest.fixture(scope="module", params=["office", "quarry", "marsyard"])
def scene(request) -> World:
    return World.from_scene(request.param)


def test_every_scene_loads_renders_and_has_ground_truth(scene: World) -> None:
    assert scene.scene_name in ("office", "quarry", "marsyard")
    assert scene.rover_pose() == (0.0, 0.0, 0.0)
    hf = scene.terrain
    assert np.isfinite(hf.heights).all() and 0.0 < hf.albedo.min() and hf.albedo.max() < 1.0
    scene.set_ptu(0.0, -25.0)
    r = scene.render_sensor("tof", 176, 144)
    assert np.isfinite(r.depth).mean() > 0.95  # looking down at the ground ahead
    assert 0.0 < float(np.nanmin(r.depth)) and float(np.nanmax(r.depth)) < 15.0
    dem = scene.true_dem(0.05, (1.0, -1.0, 3.0, 1.0))
    assert dem.shape == (40, 40) and np.isfinite(dem).all()
    # the rendered points lie on the true surface (terrain pixels, bilinear truth)
    ter = r.object_id == 0
    p = r.points[ter]
    assert np.abs(hf.sample(p[:, 0], p[:, 1]) - p[:, 2]).max() < 1e-3


def test_scene_is_deterministic_by_seed() -> None:
    a = World.from_scene("office", seed=5)
    b = World.from_scene("office", seed=5)
    c = World.from_scene("office", seed=6)
    assert np.array_equal(a.terrain.heights, b.terrain.heights)
    assert np.array_equal(a.terrain.albedo, b.terrain.albedo)
    assert not np.array_equal(a.terrain.albedo, c.terrain.albedo)
    spec = {"terrain": {"bounds": [0, 0, 4, 4], "cell": 0.02,
                        "primitives": [{"type": "rocks", "n": 10, "bounds": [0, 0, 4, 4], "d": [0.1, 0.3]}]}}
    h1 = World(spec, seed=1).terrain.heights
    assert np.array_equal(h1, World(spec, seed=1).terrain.heights)
    assert not np.array_equal(h1, World(spec, seed=2).terrain.heights)
    assert World.from_scene("office").seed == load_scene_spec("office")["seed"]


def test_office_has_three_rocks_a_sandbox_with_steps_and_walls() -> None:
    w = World.from_scene("office")
    dem = w.true_dem(0.01, (-2.5, -3.0, 5.5, 3.0), include_objects=False)
    lab, n = ndimage.label(dem > 0.003)
    sizes = ndimage.sum(np.ones_like(dem), lab, range(1, n + 1))
    big = np.sort(sizes)[::-1]
    assert len(big) >= 4 and big[0] > 1.4 * 0.9 * 1e4  # the sandbox (1.6 x 1.0 m) ...
    assert (big[1:4] > 300).all() and (big[4:] < 300).all()  # ... and three rocks
    assert set(w.object_ids) >= {"wall_front", "wall_back", "wall_left", "wall_right"}
    # the sandbox frame is 0.12 m high and its steps rise in 4 cm treads
    assert float(w.true_dem(0.01, (2.195, -1.805, 2.205, -1.795))[0, 0]) == pytest.approx(0.12, abs=1e-5)


def test_golombek_rock_field_covers_the_model_area_fraction() -> None:
    k, d0, d1 = 0.1, 0.05, 1.0
    q = 1.79 + 0.152 / k
    edges, lam = golombek_counts(k, d0, d1, area=1.0, bins=400)
    mid = np.sqrt(edges[:-1] * edges[1:])
    model = k * (np.exp(-q * d0) - np.exp(-q * d1))
    assert (lam * np.pi * mid**2 / 4).sum() == pytest.approx(model, rel=0.01)
    spec = {"terrain": {"bounds": [0, 0, 12, 12], "cell": 0.01, "primitives": [
        {"type": "rock_field", "bounds": [0, 0, 12, 12], "k": k, "d_min": d0, "d_max": d1}]}}
    w = World(spec, seed=4)
    covered = float((w.terrain.heights > 1e-4).mean())
    # overlapping rocks and rocks cut by the map edge make it a little less than the model
    assert 0.8 * model < covered < 1.05 * model


def test_marsyard_and_quarry_relief() -> None:
    mars = World.from_scene("marsyard")
    dem = mars.true_dem(0.05, (5.0, 0.5, 9.0, 4.5))
    # the origin: the rover's at its start, the plane its wheels rest on, 1.3 cm over the ground there
    assert mars.rover_z() == pytest.approx(0.0, abs=1e-6)
    assert mars.true_dem(0.05, (-0.025, -0.025, 0.025, 0.025))[0, 0] == pytest.approx(-0.0131, abs=2e-3)
    assert dem.min() < np.median(dem) - 0.2  # the big crater's floor, 7.0, 2.5
    assert dem[40, 40] == pytest.approx(dem.min(), abs=0.1)
    quarry = World.from_scene("quarry")
    assert float(quarry.true_dem(0.1, (14.0, -0.5, 15.0, 0.5)).mean()) > 2.5  # top of the slope
    assert abs(float(quarry.true_dem(0.1, (0.5, -0.5, 1.5, 0.5)).mean())) < 0.1  # the floor


def test_load_scene_in_place_and_unknown_scene() -> None:
    w = World.from_scene("office")
    w.set_ptu(10.0, -5.0)
    pulses = w.trigger.pulse()
    w.move_rover(1.0, 0.0, 0.0)
    w.load_scene("quarry")
    assert w.scene_name == "quarry" and w.ptu() == (10.0, -5.0) and w.trigger.count == pulses
    assert w.rover_pose() == (0.0, 0.0, 0.0)
    with pytest.raises(FileNotFoundError, match="office"):
        World.from_scene("atlantis")


def test_marker_target_shows_its_marker() -> None:
    import cv2

    w = World.from_scene("office")
    w.set_target_visible(True)
    w.set_target_time(0.0)  # at (4.5, 1.5)
    x, y, z, _ = w.target_pose()
    assert (x, y) == pytest.approx((4.5, 1.5))
    from drivers.sim.transforms import R_BODY_FROM_OPTICAL, make_T, rot_z

    # look at its -x face from 1.2 m, level with the marker's centre (0.2 m up)
    T = make_T(rot_z(0.0) @ R_BODY_FROM_OPTICAL, (x - 1.2, y, z + 0.2))
    K = w.camera_intrinsics("left", 640, 480)
    r = w.render(K, 640, 480, T)
    assert (r.object_id == w.object_ids["target"]).sum() > 5000
    img = (r.albedo * 255).astype(np.uint8)
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250))
    corners, ids, _ = det.detectMarkers(img)
    assert ids is not None and 7 in ids.ravel()


def test_a_scene_extending_another_is_its_ground_under_its_own_seed(tmp_path) -> None:
    (tmp_path / "office_b.yaml").write_text("extends: office\nseed: 6\n")
    spec, base = load_scene_spec(tmp_path / "office_b.yaml"), load_scene_spec("office")
    assert spec["name"] == "office_b" and spec["extends"] == "office" and spec["seed"] == 6 != base["seed"]
    assert spec["terrain"] == base["terrain"] and spec["_dir"] == base["_dir"]  # its data files are the base's
    other, same = World.from_scene(tmp_path / "office_b.yaml"), World.from_scene("office", seed=6)
    assert np.array_equal(other.terrain.heights, same.terrain.heights)
    assert not np.array_equal(other.terrain.heights, World.from_scene("office").terrain.heights)
    # the held-out draws that ship: dense's and hirise's ground, seeds of their own
    for fresh, of in (("dense_fresh", "dense"), ("hirise_fresh", "hirise")):
        f, b = load_scene_spec(fresh), load_scene_spec(of)
        assert f["terrain"] == b["terrain"] and f["seed"] != b["seed"]


def test_scenes_extending_each_other_in_a_loop_are_refused(tmp_path) -> None:
    (tmp_path / "a.yaml").write_text(f"extends: {tmp_path / 'b.yaml'}\n")
    (tmp_path / "b.yaml").write_text(f"extends: {tmp_path / 'a.yaml'}\n")
    with pytest.raises(ValueError, match="in a loop"):
        load_scene_spec(tmp_path / "a.yaml")
    (tmp_path / "c.yaml").write_text("seed: 3\n")
    with pytest.raises(ValueError, match="not a scene"):
        load_scene_spec(tmp_path / "c.yaml")
