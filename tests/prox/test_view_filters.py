"""rvs-dem-import's view filters are the server's: a raw cloud with intensity, filtered by range
and reflectivity against the sensor position, keeps exactly the points ``view_from_frame``
keeps of the same frame (why: the same views must give the same DEM from the CLI as from the
server, also when they were not recorded by a DEM job)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from prox_workflows.algorithms.acquire import Frame, view_from_frame
from prox_workflows.algorithms.transforms import apply
from prox_workflows.steps.read import read_points


def test_range_and_reflectivity_filters_match_the_servers(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    h, w = 40, 50
    xyz = np.stack([rng.uniform(-2, 2, (h, w)), rng.uniform(-1.5, 1.5, (h, w)), rng.uniform(0.3, 7.0, (h, w))],
                   axis=-1).astype(np.float32)
    xyz[rng.random((h, w)) < 0.05] = np.nan
    intensity = (rng.uniform(0.5, 2.0, (h, w)) / np.maximum(xyz[..., 2], 0.3) ** 2).astype(np.float32)
    intensity[rng.random((h, w)) < 0.1] *= 0.02  # phase-wrapped far returns: implausibly weak
    c, s = np.cos(0.4), np.sin(0.4)
    T = np.array([[c, -s, 0, 1.5], [s, c, 0, -0.7], [0, 0, 1, 1.2], [0, 0, 0, 1.0]])
    frame = Frame("tof", xyz, intensity, np.eye(3), max_range=4.5, min_reflectivity=0.1)
    server = view_from_frame(0, frame, 0.0, 0.0, T).points

    defined = np.isfinite(xyz[..., 2]) & (xyz[..., 2] > 0)
    raw = np.concatenate([apply(T, xyz[defined]), intensity[defined][:, None]], axis=1)
    np.save(tmp_path / "raw.npy", raw)
    cli = read_points([tmp_path / "raw.npy"], noise="none", sensor=list(T[:3, 3]), range=[0.0, 4.5],
                      min_reflectivity=0.1)["points"]
    assert 0 < len(server) < len(raw)
    assert np.array_equal(cli, server)
