"""The track navigate writes (``nav/<name>_track.csv``): where the rover went, for the operator
and the benchmark's truth check. Rows are x, y (m) and heading (deg): the simulator's true pose,
or the GNC's reports, every :data:`STEP` driven and every :data:`TURN` turned (turns on the
spot included: the body's corners sweep ground there that a position never shows), and where
each motion ended."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from pathlib import Path

    from ..app import App

STEP = 0.05  # m
TURN = 5.0  # deg


class Track:
    def __init__(self) -> None:
        self.rows: list[tuple[float, float, float]] = []

    def __len__(self) -> int:
        return len(self.rows)

    def add(self, pose: tuple[float, float, float], end: bool = False) -> None:
        """``pose`` once it is STEP from the last row or has turned TURN; with ``end`` (a motion
        ended, the GNC stopped) always: each stop is a row, where the rover stood."""
        x, y, heading = (float(v) for v in pose)
        if self.rows and not end:
            lx, ly, lh = self.rows[-1]
            turned = abs((heading - lh + 180.0) % 360.0 - 180.0)
            if math.hypot(x - lx, y - ly) < STEP and turned < TURN:
                return
        self.rows.append((x, y, heading))

    def xy(self, since: int = 0) -> np.ndarray:
        """The positions from row ``since`` on (k x 2)."""
        return np.asarray(self.rows[since:], dtype=np.float64).reshape(-1, 3)[:, :2]

    def write(self, app: App, name: str) -> Path:
        from prox_workflows.products import write_text_atomic

        path = app.data_path("nav", f"{name}_track.csv")
        write_text_atomic(path, "x,y,heading\n" + "".join(f"{x:.4f},{y:.4f},{h:.2f}\n" for x, y, h in self.rows))
        return path
