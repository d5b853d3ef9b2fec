"""Products on disk: atomic writes (temporary file, fsync, rename), YAML sidecars, images.

A crash or a break mid-write then leaves the previous product intact, never half a file; and
every product says in its sidecar what made it, when, and from which inputs and parameters.
Shared by the server's commands, the workflow steps and the command-line tools.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import tifffile
import yaml

_UMASK = os.umask(0)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` atomically."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; products are for everyone to read
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp_path, path)
        dir_fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def write_atomic(path: Path, writer: Callable[[Path], Any]) -> Path:
    """Run ``writer(tmp_path)`` and move the result into place."""
    with atomic_path(path) as tmp:
        writer(tmp)
    return Path(path)


def write_text_atomic(path: Path, text: str) -> Path:
    return write_atomic(path, lambda p: p.write_text(text))


def write_yaml_atomic(path: Path, data: Any) -> Path:
    """Every YAML the project writes goes through ``plain``: a numpy scalar that reached a
    manifest or sidecar once made safe_dump fail mid-break and lose the recovery set."""
    return write_text_atomic(path, yaml.safe_dump(plain(data), sort_keys=False, default_flow_style=None))


def plain(value: Any) -> Any:
    """Make values YAML-safe (numpy scalars and arrays, paths, tuples)."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, float) and value != value:
        return None
    return value


def write_sidecar(product: Path, made_by: str, parameters: dict[str, Any] | None = None,
                  inputs: list[str] | None = None, **extra: Any) -> Path:
    """``<product>.yaml`` beside the product: provenance a scientist can read months later."""
    product = Path(product)
    data = {
        "product": product.name,
        "made_by": made_by,
        "time": datetime.now(UTC).isoformat(timespec="milliseconds"),
        "inputs": inputs or [],
        "parameters": plain(parameters or {}),
        **plain(extra),
    }
    return write_yaml_atomic(product.with_suffix(".yaml"), data)


def write_tiff(path: Path, image: np.ndarray, **tags: Any) -> Path:
    """A (multi-channel) TIFF, written atomically; float data stays float."""
    return write_atomic(path, lambda p: tifffile.imwrite(p, image, photometric="minisblack"
                                                          if image.ndim == 2 or image.shape[-1] not in (3, 4)
                                                          else "rgb", **tags))


def preview(image: np.ndarray, colormap: int | None = None, lo: float | None = None,
            hi: float | None = None) -> np.ndarray:
    """An 8-bit view of any image for a PNG preview: robust min/max stretch, NaN black; with a
    colour map the result is RGB, as :func:`write_png` expects."""
    img = np.asarray(image)
    if img.dtype == np.uint8:
        return img
    data = img.astype(np.float32)
    valid = np.isfinite(data)
    if not valid.any():
        return np.zeros(img.shape[:2], np.uint8)
    lo = float(np.percentile(data[valid], 1)) if lo is None else lo
    hi = float(np.percentile(data[valid], 99)) if hi is None else hi
    scaled = np.clip((data - lo) / max(hi - lo, 1e-12), 0, 1) * 255
    out = np.where(valid, scaled, 0).astype(np.uint8)
    if colormap is not None and out.ndim == 2:
        out = cv2.cvtColor(cv2.applyColorMap(out, colormap), cv2.COLOR_BGR2RGB)
        out[~valid] = 0
    return out


def write_png(path: Path, image8: np.ndarray) -> Path:
    """PNG (RGB input is converted to OpenCV's BGR order)."""
    img = image8
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)

    def write(p: Path) -> None:
        ok, buf = cv2.imencode(".png", img)
        if not ok:
            raise OSError(f"PNG encoding failed for {path.name}")
        p.write_bytes(buf.tobytes())

    return write_atomic(path, write)
