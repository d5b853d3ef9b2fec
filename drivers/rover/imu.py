"""The simulated rover's IMU, which both the sim rover and, in the simulator, the GNC read."""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.sim.rover import IMU_SIGMA_DEG

from .backend import Attitude


class SimImu:
    """The simulated rover's IMU: the true body's roll and pitch on the ground under its wheels,
    with its noise (:data:`~drivers.sim.rover.IMU_SIGMA_DEG`), seeded by the world so a mission
    is repeatable. Its error holds while the body stands as it stood: an IMU levels itself on
    gravity over time, so reads of a standing rover share one error, and two scans from one
    place are placed with the same tilt (drawn per read they stood apart by 0.1 deg, 7 mm four
    metres out, and their fusion came out worse than either scan). It is drawn again once the
    body's attitude changes, so the draws follow the rover's stands, not how often anything
    reads it: a GNC's mission, whose frames fall as its reports arrive, draws the same tilts
    however the threads were timed. The map matcher takes the tilt this leaves between the
    rolling map and the orbital one (:data:`prox_workflows.algorithms.map_match.TILT_SIGMA`)."""

    def __init__(self, world: Any) -> None:
        self.world = world
        self._rng = np.random.default_rng([int(getattr(world, "seed", 0) or 0), 11])
        self._held: tuple[tuple[float, float], np.ndarray] | None = None

    def read(self) -> Attitude:
        true = self.world.rover_attitude()
        if self._held is None or self._held[0] != true:
            self._held = (true, self._rng.normal(0.0, IMU_SIGMA_DEG, 2))
        noise = self._held[1]
        return true[0] + float(noise[0]), true[1] + float(noise[1]), IMU_SIGMA_DEG
