"""A scripted path for the tracking target: timed waypoints, linear in between."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Trajectory:
    """Waypoints ``[t, x, y]`` or ``[t, x, y, heading_deg]`` (seconds, metres, degrees).

    Before the first and after the last waypoint the target stands still, unless ``loop``
    repeats the path with the period of its last time. Heading, when not given, follows the
    direction of travel.
    """

    times: np.ndarray
    xy: np.ndarray
    heading: np.ndarray
    loop: bool = False

    @classmethod
    def from_spec(cls, waypoints: list[list[float]], loop: bool = False) -> Trajectory:
        w = np.asarray(waypoints, float)
        if w.ndim != 2 or w.shape[1] < 3 or len(w) == 0:
            raise ValueError("waypoints must be rows of [t, x, y] or [t, x, y, heading_deg]")
        if np.any(np.diff(w[:, 0]) <= 0):
            raise ValueError("waypoint times must increase")
        if w.shape[1] >= 4:
            heading = w[:, 3]
        else:
            seg = np.diff(w[:, 1:3], axis=0)
            ang = np.degrees(np.arctan2(seg[:, 1], seg[:, 0])) if len(seg) else np.zeros(0)
            heading = np.concatenate([ang, ang[-1:]]) if len(ang) else np.zeros(1)
        return cls(w[:, 0], w[:, 1:3], heading, loop)

    def at(self, t: float) -> tuple[float, float, float]:
        """x, y, heading_deg at time t."""
        if self.loop and self.times[-1] > self.times[0]:
            t = self.times[0] + (t - self.times[0]) % (self.times[-1] - self.times[0])
        x = float(np.interp(t, self.times, self.xy[:, 0]))
        y = float(np.interp(t, self.times, self.xy[:, 1]))
        # Heading: the segment's heading (no interpolation across the wrap at +-180).
        k = int(np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.times) - 1))
        return x, y, float(self.heading[k])
