"""rvs-odometry and its step: a simulated stereo sequence with a known rover motion, the YAML it
writes, and the errors a user meets (missing files, a bad calibration, images with nothing in
common)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from support.marks import long_suite

from prox_workflows.algorithms.stereo_odometry import ORDER, stereo_odometry
from prox_workflows.cli.odometry import main
from rvs_truth.motion import motion_error, sim_sequence


@pytest.fixture(scope="module")
def seq() -> dict[str, Any]:
    # 0.3 m forward and 2 deg of yaw in the quarry at 640 x 480: a normal step between two
    # navigation stops, small enough for the tracker without the descriptor fallback
    return sim_sequence("quarry", (0.3, 0.0, 2.0))


@pytest.fixture(scope="module")
def files(seq: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("vo")
    out = {}
    for key in ("left_a", "right_a", "left_b", "right_b"):
        out[key] = d / f"{key}.png"
        cv2.imwrite(str(out[key]), seq[key])
    out["calib"] = d / "calib.yaml"
    out["calib"].write_text(yaml.safe_dump({k: np.asarray(v).tolist() for k, v in seq["calib"].items()}))
    return out


@long_suite  # the CLI test below holds the same bounds on every run; this one adds B without depth
def test_a_known_simulated_motion_is_recovered(seq: dict[str, Any]) -> None:
    """Measured: 0.5 mm and 0.001 deg off over 0.3 m, with ~1100 inliers and a predicted sigma
    of 0.3 mm. The bounds (5 mm, i.e. 1.7 % of the step, and 0.05 deg) are ten times the error
    and what the server's orient tolerates per step on the simulator (0.1-0.3 % of 1 m in
    tests/prox/test_odometry.py): loose enough for a renderer or SGBM change, tight enough
    that a frame mix-up (B in A's frame vs A in B's) or a lost degree fails."""
    m = stereo_odometry(seq["left_a"], seq["right_a"], seq["left_b"], None, seq["calib"])
    dt, dr = motion_error(m.T_a_b, seq["truth"])
    assert dt < 0.005 and dr < 0.05
    assert m.inliers > 300
    # the covariance says the same order of magnitude as the error: neither blind nor absurd
    sd = np.sqrt(np.diag(m.covariance))
    assert np.all(sd > 0) and sd[:3].max() < 0.01 and sd[3:].max() < 0.1


def test_cli_prints_and_writes_the_yaml_keys(files: dict[str, Path], seq: dict[str, Any], tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "motion.yaml"
    rc = main([str(files["left_a"]), str(files["right_a"]), str(files["left_b"]), str(files["right_b"]),
               "--calib", str(files["calib"]), "-o", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert printed.startswith("tx: ") and "inliers: " in printed
    doc = yaml.safe_load(out.read_text())
    assert set(ORDER) | {"inliers", "covariance"} <= set(doc)
    cov = np.asarray(doc["covariance"])
    assert cov.shape == (6, 6) and np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
    assert doc["covariance_order"] == list(ORDER) and doc["b_depth"] is True
    truth = seq["truth"]
    assert [doc["tx"], doc["ty"], doc["tz"]] == pytest.approx(truth[:3, 3].tolist(), abs=0.005)
    rvec = np.degrees(cv2.Rodrigues(np.ascontiguousarray(truth[:3, :3]))[0].ravel())
    assert [doc["rx"], doc["ry"], doc["rz"]] == pytest.approx(rvec.tolist(), abs=0.05)
    sd = np.sqrt(np.diag(cov))  # the predicted spread is of the error's order: neither blind nor absurd
    assert sd[:3].max() < 0.01 and sd[3:].max() < 0.1
    assert not list(tmp_path.glob("*.tmp*"))  # written atomically: nothing left beside it


def test_missing_files_are_named(files: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main([str(files["left_a"]), str(tmp_path / "nope.png"), str(files["left_b"]),
               "--calib", str(tmp_path / "nocalib.yaml")])
    err = capsys.readouterr().err
    assert rc == 2 and "no such file" in err and "nope.png" in err and "nocalib.yaml" in err


def test_a_bad_calibration_says_how_to_make_one(files: dict[str, Path], tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("K1: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n")
    rc = main([str(files["left_a"]), str(files["right_a"]), str(files["left_b"]), "--calib", str(bad)])
    err = capsys.readouterr().err
    assert rc == 2 and "not a stereo calibration" in err and "lacks" in err and "rvs-calib" in err


def test_too_few_features_is_a_clear_refusal(files: dict[str, Path], seq: dict[str, Any], tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full_like(seq["left_b"], 128))
    rc = main([str(files["left_a"]), str(files["right_a"]), str(blank), "--calib", str(files["calib"])])
    err = capsys.readouterr().err
    assert rc == 3 and "no motion" in err and "tracked" in err and "shorter step" in err
