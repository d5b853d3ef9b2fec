"""GetPtuPositions, the transform chain, the ortho-image and the DEM mesh on known geometry."""

from __future__ import annotations

import numpy as np
import pytest

from prox_workflows.algorithms.mesh import dem_mesh, write_mesh_ply
from prox_workflows.algorithms.ortho import OrthoView, ortho_image
from prox_workflows.algorithms.transforms import (
    HeadCalibration,
    T_global_from_rover,
    apply,
    camera_matrix,
    project,
    read_cal,
    write_cal,
)
from prox_workflows.steps.scan import get_ptu_positions

FOV = (43.6, 34.6)


def covered(positions: list[tuple[float, float]], fov: tuple[float, float], pan: float, tilt: float) -> bool:
    return any(abs(p - pan) <= fov[0] / 2 + 1e-9 and abs(t - tilt) <= fov[1] / 2 + 1e-9 for p, t in positions)


@pytest.mark.parametrize("view_range", [(-150, 150, -50, -15), (-20, 20, -30, -20), (0, 300, -45, 0)])
def test_ptu_positions_cover_the_range_with_overlap(view_range) -> None:
    pos = get_ptu_positions(view_range, FOV, overlap=0.2)
    for pan in np.linspace(view_range[0], view_range[1], 61):
        for tilt in np.linspace(view_range[2], view_range[3], 15):
            assert covered(pos, FOV, pan, tilt)
    pans = sorted({p for p, _ in pos})
    if len(pans) > 1:
        assert max(np.diff(pans)) <= FOV[0] * (1 - 0.2) + 1e-6
    # serpentine: consecutive views differ in one axis only
    for (p0, t0), (p1, t1) in zip(pos, pos[1:], strict=False):
        assert p0 == p1 or t0 == t1


def test_ptu_positions_respect_limits_and_validate() -> None:
    pos = get_ptu_positions((-180, 180, -80, -10), FOV, 0.2, limits=(-159, 159, -47, 31))
    assert all(-159 <= p <= 159 and -47 <= t <= 31 for p, t in pos)
    assert get_ptu_positions((10, 10, -30, -30), FOV) == [(10.0, -30.0)]
    with pytest.raises(ValueError):
        get_ptu_positions((10, -10, 0, 0), FOV)


def test_transform_chain_points_the_camera_where_pan_and_tilt_say() -> None:
    head = HeadCalibration()
    T = T_global_from_rover(2.0, 1.0, 90.0) @ head.T_rover_from_sensor("tof", 0.0, 0.0)
    forward = T[:3, :3] @ np.array([0, 0, 1.0])  # optical axis
    assert forward == pytest.approx([0, 1, 0], abs=1e-12)  # rover heading 90: looks along +y
    T = head.T_rover_from_sensor("tof", 30.0, -45.0)
    axis = T[:3, :3] @ np.array([0, 0, 1.0])
    assert axis == pytest.approx([np.cos(np.radians(30)) * np.cos(np.radians(45)),
                                  np.sin(np.radians(30)) * np.cos(np.radians(45)), -np.sin(np.radians(45))], abs=1e-12)
    # the camera centre sits on the tilt axis plus the mount offset
    assert T[:3, 3] == pytest.approx(np.array([0.10, 0, 1.26]) + axis * 0.06, abs=1e-12)


@pytest.mark.parametrize("heading,roll,pitch", [(0.0, 0.0, 8.0), (35.0, -6.0, 3.0), (-120.0, 12.0, -9.0)])
def test_a_tilted_rover_frame_lies_on_the_plane_its_attitude_gives(heading: float, roll: float, pitch: float) -> None:
    """The frames' rotation and the set-down's wheel plane read roll and pitch one way: the
    body's x and y axes, and so every wheel hub, lie on the plane contact_plane tips by them, and
    the nose rises with pitch, the left side with roll."""
    from drivers.sim.rover import RoverBody, resting_pose
    from prox_workflows.algorithms.bounds_map import contact_plane

    T = T_global_from_rover(1.0, -2.0, heading, 0.3, roll, pitch)
    gx, gy = contact_plane(heading, roll, pitch)
    for axis in (np.array([1.0, 0, 0]), np.array([0, 1.0, 0])):
        d = T[:3, :3] @ axis
        assert d[2] == pytest.approx(gx * d[0] + gy * d[1], abs=1e-12)
    assert np.sign(T[2, 0]) == np.sign(pitch) and np.sign(T[2, 1]) == np.sign(roll)
    # a rover resting on that plane reads back the same attitude; its origin is where its wheels'
    # lowest points meet the centre, over the plane by what a round wheel on its uphill edge
    # stands off a slope
    body = RoverBody()
    z, r, p = resting_pose(body, lambda x, y: 0.3 + gx * (x - 1.0) + gy * (y + 2.0), (1.0, -2.0, heading))
    assert (r, p) == pytest.approx((roll, pitch), abs=1e-6)
    rise = np.hypot(gx, gy)
    assert 0.3 <= z <= 0.3 + body.wheel_width / 2 * rise + body.wheel_radius * (np.hypot(1, rise) - 1) + 1e-4


def test_camera_matrix_projects_and_cal_round_trips(tmp_path) -> None:
    K = np.array([[200.0, 0, 87.5], [0, 200.0, 71.5], [0, 0, 1]])
    head = HeadCalibration()
    T = head.T_rover_from_sensor("tof", 10.0, -30.0)
    pts_cam = np.array([[0.0, 0.0, 2.0], [0.3, -0.2, 1.5]])
    pts = apply(T, pts_cam).astype(np.float64)
    u, v, d = project(camera_matrix(K, T), pts)
    assert u == pytest.approx([87.5, 87.5 + 200 * 0.3 / 1.5], abs=1e-4)
    assert v == pytest.approx([71.5, 71.5 - 200 * 0.2 / 1.5], abs=1e-4)
    assert d == pytest.approx([2.0, 1.5], abs=1e-5)
    cal = read_cal(write_cal(tmp_path / "v.cal", K, T, (176, 144)))
    assert np.allclose(cal["P"], camera_matrix(K, T), atol=1e-6)


def test_ortho_takes_the_unoccluded_nearest_view() -> None:
    xs = np.array([0.5, 1.5])
    ys = np.array([0.5])
    dem = np.zeros((1, 2), np.float32)
    # two top-down cameras above the cells, at heights 2 and 3; the nearer one is "occluded" at cell 0
    views = []
    for height, value in ((2.0, 100.0), (3.0, 200.0)):
        T = np.eye(4)
        T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # optical z points down
        T[:3, 3] = [1.0, 0.5, height]
        K = np.array([[20.0, 0, 5], [0, 20.0, 5], [0, 0, 1]])
        P = camera_matrix(K, T)
        depth = np.full((11, 11), height, np.float32)
        if height == 2.0:
            depth[5, 0] = 1.0  # something in front of cell 0 (u = 5 - 5 = 0)
        views.append(OrthoView(P, np.full((11, 11), value, np.float32), depth))
    ortho, which = ortho_image(dem, xs, ys, views)
    assert which.tolist() == [[1, 0]]
    assert ortho[0, 0] > ortho[0, 1] > 0  # 200 from the far view, 100 from the near one
    ortho, which = ortho_image(np.array([[np.nan, 0]], np.float32), xs, ys, views)
    assert ortho[0, 0] == 0 and which[0, 0] == -1


def test_mesh_faces_only_over_defined_cells(tmp_path) -> None:
    dem = np.array([[0, 1, np.nan], [0, 1, 2], [0, 1, 2]], np.float32)
    xs, ys = np.array([0.5, 1.5, 2.5]), np.array([2.5, 1.5, 0.5])
    v, f, c = dem_mesh(dem, xs, ys)
    assert len(v) == 8 and len(f) == 6  # 3 full quads
    normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert (normals[:, 2] > 0).all()
    path = write_mesh_ply(tmp_path / "m.ply", v, f, c)
    head = path.read_bytes()[:400].decode("ascii", "replace")
    assert "element vertex 8" in head and "element face 6" in head
