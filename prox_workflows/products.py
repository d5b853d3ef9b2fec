"""Products on disk: atomic writes (temporary file, fsync, rename), YAML sidecars, images.

A crash or a break mid-write then leaves the previous product intact, never half a file; and
every product says in its sidecar what made it, when, and from which inputs and parameters.
Shared by the server's commands, the workflow steps and the command-line tools.

A product of many files (a DEM's ~30 layers, previews and sidecars) is written as one set
(:func:`product_set`): every file goes to its temporary name first, then a commit journal lists
the renames, then they are made. A kill before the journal leaves the previous set whole (the
temporaries are removed at the next start, :func:`finish_product_sets`); a kill after it is
rolled forward at the next start. Either way a reader never gets layers from two runs.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import tempfile
import uuid
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import tifffile
import yaml

from rvs_params.plain import plain

_UMASK = os.umask(0)
os.umask(_UMASK)


# the renames the product set being written in this thread (or task) still owes: (temporary, final)
_PENDING: contextvars.ContextVar[list[tuple[Path, Path]] | None] = contextvars.ContextVar("product_set",
                                                                                       default=None)
JOURNAL_GLOB = ".products-*.commit"
TEMP_GLOB = ".*.tmp*"  # atomic_path's temporaries: .<name>.<random>.tmp<suffix>


def _fsync_dir(folder: Path) -> None:
    dir_fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


@contextlib.contextmanager
def atomic_path(path: Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path`` atomically (inside
    a :func:`product_set`, when the whole set is committed)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp" + path.suffix, dir=path.parent)
    os.close(fd)
    os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600; products are for everyone to read
    tmp_path = Path(tmp)
    owed = False
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        pending = _PENDING.get()
        if pending is not None:
            pending.append((tmp_path, path))
            owed = True
        else:
            os.replace(tmp_path, path)
            _fsync_dir(path.parent)
    finally:
        if not owed and tmp_path.exists():
            tmp_path.unlink()


@contextlib.contextmanager
def product_set(folder: Path) -> Iterator[None]:
    """Every atomic write in the block (this thread's) lands together when the block ends, or
    none does if it raises; the commit journal goes in ``folder``. Nested sets join the outer one."""
    if _PENDING.get() is not None:
        yield
        return
    pending: list[tuple[Path, Path]] = []
    token = _PENDING.set(pending)
    try:
        yield
    except BaseException:
        for tmp, _ in pending:
            tmp.unlink(missing_ok=True)
        raise
    finally:
        _PENDING.reset(token)
    _commit(Path(folder), pending)


def _commit(folder: Path, pending: list[tuple[Path, Path]]) -> None:
    last: dict[Path, Path] = {}
    for tmp, final in pending:  # a file written twice in one set: the later write wins
        if final in last:
            last[final].unlink(missing_ok=True)
        last[final] = tmp
    if not last:
        return
    folder.mkdir(parents=True, exist_ok=True)
    journal = folder / f".products-{uuid.uuid4().hex}.commit"
    renames = [[os.path.relpath(tmp, folder), os.path.relpath(final, folder)] for final, tmp in last.items()]
    with atomic_path(journal) as tmp:
        tmp.write_text(yaml.safe_dump(renames))
    _roll_forward(journal)


def _roll_forward(journal: Path) -> int:
    folder = journal.parent
    renames = yaml.safe_load(journal.read_text()) or []
    done = 0
    for tmp, final in renames:
        if (folder / tmp).exists():
            os.replace(folder / tmp, folder / final)
            done += 1
    for parent in {(folder / final).parent for _, final in renames}:
        _fsync_dir(parent)
    journal.unlink()
    _fsync_dir(folder)
    return done


def finish_product_sets(root: Path) -> dict[str, int]:
    """At start, under ``root``: complete the product sets whose commit a crash cut short (their
    journal is there), then remove the temporaries nothing will rename (a set or a file a crash
    cut short before its commit). Returns how many files each did."""
    root = Path(root)
    if not root.is_dir():
        return {"rolled_forward": 0, "removed": 0}
    # a journal's own temporary (.products-*.commit.<random>.tmp.commit) was never committed
    rolled = sum(_roll_forward(j) for j in sorted(root.rglob(JOURNAL_GLOB)) if ".tmp" not in j.name)
    removed = 0
    for stray in root.rglob(TEMP_GLOB):
        if stray.is_file():
            stray.unlink(missing_ok=True)
            removed += 1
    return {"rolled_forward": rolled, "removed": removed}


def write_atomic(path: Path, writer: Callable[[Path], Any]) -> Path:
    """Run ``writer(tmp_path)`` and move the result into place."""
    with atomic_path(path) as tmp:
        writer(tmp)
    return Path(path)


def write_text_atomic(path: Path, text: str) -> Path:
    return write_atomic(path, lambda p: p.write_text(text))


def write_yaml_atomic(path: Path, data: Any) -> Path:
    """Every YAML the project writes goes through ``plain``: a numpy scalar that reaches a
    manifest or sidecar makes safe_dump fail, mid-break that would lose the recovery set."""
    return write_text_atomic(path, yaml.safe_dump(plain(data), sort_keys=False, default_flow_style=None))


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
