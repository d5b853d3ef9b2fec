"""The stereo steps: a pair matched into a disparity, and visual odometry from image files."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..algorithms import odometry as od
from ..algorithms.stereo import Disparity, SgbmParams, disparity, load_calibration, read_image
from ..algorithms.stereo_odometry import stereo_odometry
from ..engine import step


@step("stereo_disparity", outputs={"disparity": "Disparity"})
def stereo_disparity(left: np.ndarray, right: np.ndarray, calib: Any, params: dict[str, Any] | None = None
                     ) -> Disparity:
    """SGBM with left-right check, speckle filter and texture mask (:func:`disparity`)."""
    return disparity(left, right, calib, SgbmParams.from_dict(params or {}))


@step("stereo_odometry", outputs={"motion": "dict"})
def stereo_odometry_files(left_a: str | Path, right_a: str | Path, left_b: str | Path,
                          right_b: str | Path | None, calib: str | Path,
                          params: dict[str, Any] | None = None) -> dict[str, Any]:
    """:func:`stereo_odometry` on image files (what rvs-odometry runs): the motion's YAML keys.
    ``params`` sets OdometryParams fields. Missing files raise FileNotFoundError naming them."""
    paths = [Path(x) for x in (left_a, right_a, left_b, right_b, calib) if x is not None]
    missing = [str(x) for x in paths if not x.exists()]
    if missing:
        raise FileNotFoundError(f"no such file: {', '.join(missing)}")
    try:
        cal = load_calibration(calib)
    except (ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{calib}: not a stereo calibration ({exc}); make one with rvs-calib stereo "
                         "(or rvs-calib sim-truth for the simulator)") from exc
    p = od.OdometryParams(**(params or {}))
    images = [read_image(x) for x in (left_a, right_a, left_b)]
    rb = read_image(right_b) if right_b is not None else None
    return stereo_odometry(*images, rb, cal, p).as_dict()
