"""The scan's steps: where the PTU points (GetPtuPositions), the acquisition the caller supplies,
and what a scan's views say about themselves (their sensors' conflict rule, their files)."""

from __future__ import annotations

from typing import Any

from ..algorithms.acquire import View
from ..algorithms.ptu_positions import plan
from ..engine import step


@step("get_ptu_positions", outputs={"positions": "list"})
def get_ptu_positions(
    view_range: list[float] | tuple[float, float, float, float],
    fov: tuple[float, float],
    overlap: float = 0.2,
    limits: tuple[float, float, float, float] | None = None,
    motion: dict[str, dict[str, float]] | None = None,
    start: list[float] | None = None,
    order: str | None = None,
) -> list[tuple[float, float]]:
    """``view_range`` = (pan_min, pan_max, tilt_min, tilt_max) in degrees; ``fov`` = (h, v);
    ``motion`` and ``start`` (the PTU's, see :func:`plan`) choose the order; ``order`` "rows"
    keeps the rows from the lowest pan and tilt whatever the motion (default "fastest")."""
    return plan(view_range, fov, overlap, limits, motion, tuple(start) if start is not None else None,
                order or "fastest")


@step("acquire", outputs={"views": "list[View]"})
def acquire(positions: list[tuple[float, float]], progress: Any = None, cancelled: Any = None) -> list[View]:
    """The declaration of the acquisition step; its implementation is the caller's.

    The server supplies it (its PTU and sensors: ``run_workflow(..., steps={"acquire": fn})``),
    so this package never imports a driver; offline a script reads recorded views instead
    (``read_views``).
    """
    raise NotImplementedError("acquire is supplied by the server; offline, read recorded views with read_views")


@step("scan_rule", outputs={"within_scan": "str"})
def scan_rule(views: list[View]) -> str:
    """How views of one scan settle a conflict, from the sensors that took them: views of one
    sensor, the higher wins (a rock's top over its foot); ToF and stereo together, the gate
    rejects what the other sensor contradicts. Derived from the views, so the server and a
    reprocessing of its recorded views choose alike."""
    return "inflate" if len({v.sensor for v in views}) > 1 else "higher"


@step("join_views", outputs={"views": "list[View]"})
def join_views(earlier: list[View] | None, new: list[View]) -> list[View]:
    """Views a stopped acquisition left behind, then the new ones (newest last)."""
    return list(earlier or []) + list(new)


@step("view_files", outputs={"inputs": "list[str]"})
def view_files(views: list[View], folder: str | None = None) -> list[str]:
    """The recorded images the views came from, as the products' sidecars cite them."""
    prefix = f"{folder}/" if folder else ""
    return [f"{prefix}{v.files['image']}" for v in views if v.files]
