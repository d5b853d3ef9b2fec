"""The simulated rover's IMU, which both the sim rover and, in the simulator, the GNC read."""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.sim.rover import IMU_SIGMA_DEG

from .backend import Attitude


class SimImu:
    """The simulated rover's IMU: the true body's roll and pitch on the ground under its wheels,
    with its noise (:data:`~drivers.sim.rover.IMU_SIGMA_DEG`) drawn for each read, seeded by the
    world so a mission is repeatable. A real IMU's error at rest is mostly a slow bias, which
    reads of a standing rover share; held so while the body stood, the see loop's standing
    looks shared one tilt and the map matcher's fix on marsyard's slopes came out 23 cm off
    against the 4.4 cm it claimed (tests/navigation/test_localise.py): the matcher takes no
    tilt between the maps, which that bias needs first."""

    def __init__(self, world: Any) -> None:
        self.world = world
        self._rng = np.random.default_rng([int(getattr(world, "seed", 0) or 0), 11])

    def read(self) -> Attitude:
        roll, pitch = self.world.rover_attitude()
        noise = self._rng.normal(0.0, IMU_SIGMA_DEG, 2)
        return roll + float(noise[0]), pitch + float(noise[1]), IMU_SIGMA_DEG
