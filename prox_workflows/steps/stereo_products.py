"""The stereo steps as a script chains them (``rvs-stereo`` is a front-end to ``stereo.yaml``):
read a pair as taken, match it (the server's stereo DEMs match with the same
:func:`prox_workflows.steps.stereo.disparity`), write the disparity and the point cloud."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import tifffile

from ..engine import step
from ..pointcloud import write_ply
from ..products import preview, product_set, write_atomic, write_png, write_sidecar, write_tiff
from .stereo import Disparity, SgbmParams, cloud, disparity, load_calibration, sigma_d_for, to_gray8


def read_image(path: str | Path) -> np.ndarray:
    """TIFF (tifffile), .npy, or anything OpenCV reads (PNG, PGM, JPEG; colour returned as RGB)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix in (".tif", ".tiff"):
        return np.asarray(tifffile.imread(path))
    if suffix == ".npy":
        return np.load(path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: not an image OpenCV can read")
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    return img


@step("read_stereo_pair", outputs={"left": "array", "right": "array", "calib": "any"})
def read_stereo_pair(left: str | Path, right: str | Path, calib: str | Path) -> dict[str, Any]:
    """A pair as taken and its calibration (image_size, K1 D1 K2 D2 R T)."""
    return {"calib": load_calibration(calib), "left": read_image(left), "right": read_image(right)}


@step("stereo_disparity", outputs={"disparity": "Disparity"})
def stereo_disparity(left: np.ndarray, right: np.ndarray, calib: Any, params: dict[str, Any] | None = None
                     ) -> Disparity:
    """SGBM with left-right check, speckle filter and texture mask (:func:`disparity`)."""
    return disparity(left, right, calib, SgbmParams.from_dict(params or {}))


@step("write_stereo", outputs={"files": "dict"})
def write_stereo(disparity: Disparity, left: np.ndarray, params: dict[str, Any] | None = None,
                 disparity_path: str | Path | None = None, rectified_path: str | Path | None = None,
                 cloud_path: str | Path | None = None, sigma_d: float | None = None, max_depth: float | None = None,
                 made_by: str | None = None, inputs: list[str] | None = None) -> dict[str, Any]:
    """The disparity (left and/or rectified geometry) and the point cloud in the left camera
    frame, each with its sidecar; returns what was written and the figures it printed."""
    disp = disparity
    p = SgbmParams.from_dict(params or {})
    made_by = made_by or "rvs-prox"
    inputs = list(inputs or [])
    valid = np.isfinite(disp.left)
    files: dict[str, Any] = {"lines": []}
    lines: list[str] = files["lines"]
    named = [Path(q) for q in (disparity_path, rectified_path, cloud_path) if q is not None]
    with product_set(named[0].parent if named else Path(".")):  # the disparity, cloud and sidecars land together
        if disparity_path is not None:
            path = Path(disparity_path)
            write_tiff(path, disp.left.astype(np.float32))
            write_png(path.with_suffix(".png"), preview(disp.left, cv2.COLORMAP_JET))
            write_sidecar(path, made_by, p.to_dict(), inputs, units="px", nan="invalid",
                          geometry="left original image", focal_px=disp.rect.focal, baseline_m=disp.rect.baseline,
                          valid_share=float(valid.mean()))
            files["disparity"] = path
            lines.append(f"disparity -> {path}")
        if rectified_path is not None:
            path = Path(rectified_path)
            write_tiff(path, disp.rectified.astype(np.float32))
            write_sidecar(path, made_by, p.to_dict(), inputs, units="px", nan="invalid",
                          geometry="rectified left image (cv2.stereoRectify, alpha 0)", P1=np.asarray(disp.rect.P1),
                          R1=np.asarray(disp.rect.R1), Q=np.asarray(disp.rect.Q))
            files["rectified"] = path
            lines.append(f"rectified disparity -> {path}")
        if cloud_path is not None:
            path = Path(cloud_path)
            sd = sigma_d_for(p.scale) if sigma_d is None else sigma_d
            pts, sig, pix = cloud(disp, sd)
            if max_depth is not None:
                keep = pts[:, 2] <= max_depth
                pts, sig, pix = pts[keep], sig[keep], pix[keep]
            if path.suffix.lower() == ".npy":
                write_atomic(path, lambda t: _save_npy(t, pts))
            else:
                grey = to_gray8(left)[pix[:, 0], pix[:, 1]]
                write_ply(path, np.column_stack([pts, grey.astype(np.float32)]),
                          np.repeat(grey[:, None], 3, axis=1), comment="rvs-stereo cloud, left camera frame (m)")
            write_sidecar(path, made_by, p.to_dict(), inputs, frame="left camera (x right, y down, "
                          "z forward)", units="m", points=len(pts), intensity="left image grey value",
                          noise_model="sigma_z = z^2 * sigma_d / (b * f)", sigma_d_px=sd,
                          baseline_m=disp.rect.baseline, focal_px=disp.rect.focal,
                          sigma_z_m={"median": float(np.median(sig)) if len(sig) else None,
                                     "max": float(np.max(sig)) if len(sig) else None})
            files["cloud"] = path
            lines.append(f"{len(pts)} points -> {path}")
    return files


def _save_npy(path: Path, pts: np.ndarray) -> None:
    with open(path, "wb") as fh:
        np.save(fh, pts.astype(np.float32), allow_pickle=False)
