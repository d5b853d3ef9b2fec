"""The stereo calibration file of the real pair: OpenCV's stereoCalibrate names in YAML.

Keys: K1 D1 K2 D2 (intrinsics and distortion of left and right), R T (x_right = R x_left + T,
metres) and image_size [width, height]. The simulated pair returns the world's truth instead.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from drivers.base import DeviceError

KEYS = ("K1", "D1", "K2", "D2", "R", "T", "image_size")
SHAPES = {"K1": (3, 3), "K2": (3, 3), "R": (3, 3), "T": (3,)}


def load_calibration(path: str | os.PathLike[str], size: tuple[int, int] | None = None) -> dict[str, Any]:
    """Read and check a calibration file; DeviceError (naming the file) when it is unusable."""
    source = Path(path)
    try:
        doc = yaml.safe_load(source.read_text())
    except FileNotFoundError:
        raise DeviceError("stereo", f"calibration file {source} not found (drivers.stereo.calibration)") from None
    except yaml.YAMLError as exc:
        raise DeviceError("stereo", f"calibration file {source} is not valid YAML: {exc}") from None
    if not isinstance(doc, dict):
        raise DeviceError("stereo", f"calibration file {source} must be a mapping with {', '.join(KEYS)}")
    missing = [k for k in KEYS if k not in doc]
    if missing:
        raise DeviceError("stereo", f"calibration file {source} lacks {', '.join(missing)}")
    out: dict[str, Any] = {"source": str(source)}
    for key in KEYS[:-1]:
        arr = np.asarray(doc[key], dtype=np.float64)
        want = SHAPES.get(key)
        if want is not None:
            arr = arr.reshape(want) if arr.size == int(np.prod(want)) else arr
            if arr.shape != want:
                raise DeviceError("stereo", f"calibration file {source}: {key} must have shape {want}")
        else:
            arr = arr.ravel()
        out[key] = arr
    out["image_size"] = [int(v) for v in doc["image_size"]]
    if size is not None and tuple(out["image_size"]) != tuple(size):
        out["note"] = (
            f"calibrated at {out['image_size'][0]}x{out['image_size'][1]}, "
            f"requested {size[0]}x{size[1]}: recalibrate for this resolution mode"
        )
    return out


def save_calibration(path: str | os.PathLike[str], calib: dict[str, Any]) -> Path:
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    doc = {k: np.asarray(calib[k]).tolist() for k in KEYS[:-1]}
    doc["image_size"] = [int(v) for v in calib["image_size"]]
    target.write_text(yaml.safe_dump(doc, sort_keys=False))
    return target
