"""A simulated ToF frame of a scene as the see loop fuses it into its bounds map: the returns with
the range noise the camera is told of, their height sigmas and horizontal errors."""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.sim.world import World
from prox_workflows.algorithms.noise import tof_height_variance, tof_horizontal_sigma, tof_sigma


def tof_frame(world: World, rng: np.random.Generator, pan: float, across: bool = True) -> dict[str, Any]:
    """One frame of ``world`` at ``pan`` (tilt -35 deg) as :meth:`BoundsMap.fuse`'s arguments
    (``points``, ``sigma``, ``origin``, then ``args`` and ``kwargs``); ``across``: each return's
    horizontal error an ellipse along its ray (a quarter of it across), as the see loop fuses its
    frames, else a disc."""
    from drivers.tof.constants import HEIGHT, USABLE_RANGE, WIDTH

    world.set_ptu(pan, -35.0)
    origin = world.sensor_pose("tof")[:3, 3]
    view = world.render_sensor("tof", WIDTH, HEIGHT)
    ranges = view.range.reshape(-1)
    keep = np.isfinite(ranges) & (ranges < USABLE_RANGE) & (view.object_id.reshape(-1) != 1)
    pts, r = view.points.reshape(-1, 3)[keep].astype(np.float64), ranges[keep].astype(np.float64)
    noisy = pts + (pts - origin) / r[:, None] * (tof_sigma(r) * rng.standard_normal(len(r)))[:, None]
    along = tof_horizontal_sigma(noisy, origin)
    return {"points": noisy, "sigma": np.sqrt(tof_height_variance(noisy, origin)), "origin": origin,
            "args": (USABLE_RANGE, along), "kwargs": {"sigma_across": along / 4 if across else None}}
