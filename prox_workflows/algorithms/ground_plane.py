"""Ground-plane alignment (seed 003 sect. 4.3.1): the sensor head's tilt, roll and height
relative to the rover, from the ground it sees while the rover stands still on level ground.

Per frame, the largest plane in the sensor's point cloud by RANSAC (then least squares on its
inliers) gives the ground in the sensor frame as n . x + d = 0, with n pointing at the sensor
so that d is the sensor's height above it. Several frames are averaged (the thesis averages
the rotations as quaternions; for normals a few degrees apart the normalised mean is the same).

The rover frame's z axis is the ground's normal by definition (the rover stands on it), so the
measured normal fixes two angles of the sensor's orientation on the rover. They are given to
the sensor's mount (its roll and pitch in the PTU's tilt frame, yaw kept: the ground cannot see
a turn about the vertical), solved exactly for the PTU angles of the measurement, so a mount
misalignment in roll is recovered in full even when the PTU looks down steeply (where a roll
of the mount moves the ground normal by only cos(tilt) of it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .transforms import R_BODY_FROM_OPTICAL, HeadCalibration, rpy


@dataclass
class Plane:
    """n . x + d = 0 (|n| = 1, n towards the sensor: d > 0 is the sensor's distance to it)."""

    normal: np.ndarray
    d: float
    inliers: int
    rms: float  # m, inliers' distance to the plane
    share: float  # inliers / points


def fit_plane(points: np.ndarray, threshold: float = 0.02, iterations: int = 300,
              rng: np.random.Generator | int | None = 0) -> Plane:
    """The plane most points lie on (within ``threshold`` m), refitted by least squares on them."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 3:
        raise ValueError(f"a plane needs at least 3 points, got {len(pts)}")
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    # score on a subsample: the ranking of candidate planes does not need every point
    sample = pts if len(pts) <= 20000 else pts[gen.choice(len(pts), 20000, replace=False)]
    best_n, best_d, best_count = None, 0.0, -1
    for _ in range(iterations):
        a, b, c = sample[gen.choice(len(sample), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-9:
            continue
        n /= norm
        d = -float(n @ a)
        count = int(np.count_nonzero(np.abs(sample @ n + d) < threshold))
        if count > best_count:
            best_n, best_d, best_count = n, d, count
    if best_n is None:
        raise ValueError("no plane found: the points are collinear")
    n, d = best_n, best_d
    for _ in range(3):  # least squares on the inliers, which may then change a little
        inl = np.abs(pts @ n + d) < threshold
        if inl.sum() < 3:
            break
        sel = pts[inl]
        centroid = sel.mean(axis=0)
        _, _, vt = np.linalg.svd(sel - centroid, full_matrices=False)
        n = vt[2]
        d = -float(n @ centroid)
    if d < 0:
        n, d = -n, -d
    dist = np.abs(pts @ n + d)
    inl = dist < threshold
    rms = float(np.sqrt(np.mean(dist[inl] ** 2))) if inl.any() else float("nan")
    return Plane(n, d, int(inl.sum()), rms, float(inl.mean()))


def average_planes(planes: list[Plane]) -> tuple[Plane, float]:
    """The mean plane of several frames (normalised mean normal, mean distance, weighted by
    inliers) and the largest angle (deg) between a frame's normal and the mean."""
    if not planes:
        raise ValueError("no planes to average")
    w = np.array([p.inliers for p in planes], dtype=np.float64)
    w = w / w.sum() if w.sum() > 0 else np.full(len(planes), 1.0 / len(planes))
    normals = np.array([p.normal for p in planes])
    n = w @ normals
    n /= np.linalg.norm(n)
    d = float(w @ np.array([p.d for p in planes]))
    rms = float(np.sqrt(w @ np.array([p.rms ** 2 for p in planes])))
    spread = max(math.degrees(math.acos(float(np.clip(m @ n, -1.0, 1.0)))) for m in normals)
    mean = Plane(n, d, int(sum(p.inliers for p in planes)), rms, float(np.mean([p.share for p in planes])))
    return mean, spread


def rpy_of(R: np.ndarray) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in degrees with R = Rz(yaw) Ry(pitch) Rx(roll), as :func:`rpy`."""
    yaw = math.degrees(math.atan2(R[1, 0], R[0, 0]))
    pitch = math.degrees(math.asin(float(np.clip(-R[2, 0], -1.0, 1.0))))
    roll = math.degrees(math.atan2(R[2, 1], R[2, 2]))
    return roll, pitch, yaw


def sensor_attitude(T_rover_sensor: np.ndarray) -> tuple[float, float, float]:
    """(tilt, roll, yaw) of a sensor on the rover, degrees: tilt as the PTU counts it (negative
    looking down), roll about the viewing direction, yaw counter-clockwise from forward."""
    R_body = T_rover_sensor[:3, :3] @ R_BODY_FROM_OPTICAL.T
    roll, pitch, yaw = rpy_of(R_body)
    return -pitch, roll, yaw


@dataclass
class GroundAlignment:
    """What one ground alignment found and the mount values that explain it."""

    sensor: str
    mounts: dict[str, dict[str, list[float]]]  # corrected mounts (xyz, rpy) of every sensor touched
    rpy_before: list[float]
    rpy_after: list[float]
    tilt: float  # deg: the sensor's measured tilt on the rover (PTU convention, negative down)
    roll: float  # deg: its measured roll about the viewing direction
    height: float  # m: the sensor's optical centre above the ground plane
    ground_z: float  # m: the ground plane's height in the rover frame at the rover origin (0 ideally)
    misalignment: float  # deg: angle between the normal seen with the old mounts and the rover's z
    residual: float  # m: RMS distance of the inliers to their plane
    points: int  # inliers over all frames
    spread: float  # deg: largest deviation of one frame's normal from the mean
    normal_rover: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(3))

    @property
    def d_roll(self) -> float:
        return self.rpy_after[0] - self.rpy_before[0]

    @property
    def d_pitch(self) -> float:
        return self.rpy_after[1] - self.rpy_before[1]

    def as_dict(self) -> dict[str, Any]:
        return {"sensor": self.sensor, "tilt": self.tilt, "roll": self.roll, "height": self.height,
                "ground_z": self.ground_z, "misalignment": self.misalignment, "residual": self.residual,
                "points": self.points, "spread": self.spread, "rpy_before": self.rpy_before,
                "rpy_after": self.rpy_after, "mounts": self.mounts}


def align_mount(head: HeadCalibration, sensor: str, pan: float, tilt: float, plane: Plane,
                followers: tuple[str, ...] = (), stats: tuple[int, float] | None = None) -> GroundAlignment:
    """The mount roll and pitch of ``sensor`` that make the measured ground (``plane``, in the
    sensor frame, seen at PTU ``pan``/``tilt``) level in the rover frame.

    ``followers`` are sensors rigidly tied to it (the right camera of a stereo pair measured
    through the left one): their orientation gets the same correction.
    ``stats`` is (points, spread) to report; default from the plane itself.
    """
    m = head.mounts[sensor]
    r0, p0, y0 = (float(v) for v in m.get("rpy", (0.0, 0.0, 0.0)))
    n_s = np.asarray(plane.normal, dtype=np.float64)

    def normal_rover(roll: float, pitch: float) -> np.ndarray:
        trial = HeadCalibration(head.ptu_base, head.tilt_offset, {k: dict(v) for k, v in head.mounts.items()})
        trial.mounts[sensor] = {"xyz": list(m["xyz"]), "rpy": [roll, pitch, y0]}
        return trial.T_rover_from_sensor(sensor, pan, tilt)[:3, :3] @ n_s

    # imported here: the server and the CLIs start without scipy.optimize (0.2-0.3 s)
    from scipy.optimize import least_squares

    before = normal_rover(r0, p0)
    misalignment = math.degrees(math.acos(float(np.clip(before[2], -1.0, 1.0))))
    sol = least_squares(lambda x: normal_rover(x[0], x[1])[:2] * 1e3, np.array([r0, p0]), method="lm",
                        xtol=1e-12, ftol=1e-12)
    r1, p1 = (float(v) for v in sol.x)
    R_old = rpy(r0, p0, y0)
    R_new = rpy(r1, p1, y0)
    Q = R_new @ R_old.T  # the correction in the tilt frame, about the sensor's centre
    mounts = {sensor: {"xyz": [float(v) for v in m["xyz"]], "rpy": [r1, p1, y0]}}
    for other in followers:  # turned in place: where the pair pivots, the ground cannot tell
        f = head.mounts[other]
        R_f = Q @ rpy(*(float(v) for v in f.get("rpy", (0.0, 0.0, 0.0))))
        mounts[other] = {"xyz": [float(v) for v in f["xyz"]], "rpy": list(rpy_of(R_f))}
    fixed = HeadCalibration(head.ptu_base, head.tilt_offset, {k: dict(v) for k, v in head.mounts.items()})
    fixed.mounts.update(mounts)
    T = fixed.T_rover_from_sensor(sensor, pan, tilt)
    att_tilt, att_roll, _ = sensor_attitude(T)
    n_r = T[:3, :3] @ n_s
    ground_z = float(T[2, 3] - plane.d)  # sensor height in the rover frame minus its height above ground
    points, spread = stats if stats is not None else (plane.inliers, 0.0)
    return GroundAlignment(sensor, mounts, [r0, p0, y0], [r1, p1, y0], att_tilt, att_roll, float(plane.d),
                           ground_z, misalignment, plane.rms, points, spread, n_r)
