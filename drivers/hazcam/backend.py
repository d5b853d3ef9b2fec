"""The body hazard cameras' settings and the small surface each backend fills in.

A backend only delivers the two images of one pair, exposed together, and the time it took
them. Which pairs run, where each sits on the body, its lens model, the stereo matching and the
noise of what the matching gives are the front end's (:mod:`drivers.hazcam.device`), declared
here once for every backend: the simulator renders the pairs the mounts below describe, and a
real rover's calibration files replace only the lens model, never the mount.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np

from drivers.registry import BackendRegistry, Capability
from rvs_params import Settings, param

NAME = "hazcam"
CAMERAS = ("front", "rear")  # the body's pairs, by the end of the rover they look out from
CHOICES = ("off", "front", "rear", "front,rear")
OFF_HINT = "set drivers.hazcam.cameras front,rear (or front, or rear) and reinit -device hazcam"


@dataclass
class HazcamSettings(Settings):
    """drivers.hazcam keys of the front end, shared by all backends.

    Each pair is an ideal pinhole pair (the renderer has no fisheye: MER's and MSL's hazcams are
    124 deg fisheyes, these see 90 deg across and about 74 deg down the image) whose mount is the
    point midway between its two optical centres, in the rover frame (x forward, y left, z up
    from the ground under the rover's centre), looking ``pitch`` below the horizontal along
    ``yaw`` (0 ahead, 180 behind). The left camera is half the baseline to the left of the mount.

    ``sigma_d`` is the disparity noise of the project's matcher on such pairs, measured by
    ``python -m tools.bench.hazcam``: against the disparity of the renderer's true depth, the
    matches within 2 px of the truth (the Gaussian core) have an rms error of 0.24-0.27 px on the
    simulated marsyard, hirise and dense ground at 320 x 240 to 640 x 480 (all matches 0.31-0.43
    px: 0.2-0.3 % are gross errors), and 0.32 px on Middlebury's real Motorcycle pair (robust
    sigma 0.25 px; 4.7 % of its matches are more than 2 px off, which no Gaussian sigma
    describes). 0.35 px covers both cores. The matcher's sub-pixel step also reads the disparity
    0.1 px small on average (ranges long, ground a few millimetres low), inside that sigma.
    """

    backend: str = param("sim", "hazcam backend")
    cameras: str = param("off", "which body hazard camera pairs run", choices=CHOICES)
    front_xyz: list[float] = param([0.27, 0.0, 0.35], "front pair's mount (midway between its cameras), rover "
                                   "frame", unit="m", min=-5.0, max=5.0, length=3)
    front_pitch_deg: float = param(40.0, "front pair's look below the horizontal", unit="deg", min=-90.0, max=90.0)
    front_yaw_deg: float = param(0.0, "front pair's heading in the rover frame (0 ahead)", unit="deg", min=-180.0,
                                 max=180.0)
    rear_xyz: list[float] = param([-0.27, 0.0, 0.35], "rear pair's mount (midway between its cameras), rover "
                                  "frame", unit="m", min=-5.0, max=5.0, length=3)
    rear_pitch_deg: float = param(40.0, "rear pair's look below the horizontal", unit="deg", min=-90.0, max=90.0)
    rear_yaw_deg: float = param(180.0, "rear pair's heading in the rover frame (180 behind)", unit="deg",
                                min=-180.0, max=180.0)
    hfov_deg: float = param(90.0, "horizontal field of view of each camera (an ideal pinhole)", unit="deg",
                            min=10.0, max=150.0)
    size: list[int] = param([480, 360], "image width, height (the grab's cost: 640 x 480 matches in about twice "
                            "the time, 100 ms on this 2-core machine)", unit="px", min=16, max=4096, length=2)
    baseline: float = param(0.10, "distance between the optical centres of a pair", unit="m", min=0.01, max=2.0)
    sigma_d: float = param(0.35, "disparity noise of the matched pixels (measured: tools/bench/hazcam.py)",
                           unit="px", min=0.01, max=10.0)
    min_range: float = param(0.2, "nearest depth the matcher searches (sets its disparity range): a surface "
                             "nearer than this matches wrongly, read far and low", unit="m", min=0.05, max=10.0)
    max_range: float = param(3.0, "points farther than this from the left camera are dropped", unit="m",
                             min=0.1, max=100.0)
    front_calibration: str | None = param(None, "YAML with K1 D1 K2 D2 R T image_size of the front pair (a real "
                                          "pair); null = the ideal pair declared above")
    rear_calibration: str | None = param(None, "YAML with K1 D1 K2 D2 R T image_size of the rear pair; null = "
                                         "the ideal pair declared above")


class HazcamBackend(Protocol):
    """The cameras of the configured pairs. Errors: DeviceError (DeviceInterrupted on a break)."""

    name: ClassVar[str]
    settings: ClassVar[type[Settings]]
    capabilities: ClassVar[frozenset[Capability]]
    faults: ClassVar[tuple[str, ...]]

    def open(self, cameras: tuple[str, ...]) -> None:
        """Find and set up the cameras of these pairs; DeviceError naming what is missing."""

    def close(self) -> None: ...

    def check(self, cameras: tuple[str, ...]) -> dict[str, Any]:
        """Prove each pair answers; DeviceError if one does not."""

    def capture(self, rig: Any, cancel: Any = None) -> tuple[np.ndarray, np.ndarray, float]:
        """Left and right mono8 images of the pair ``rig`` (a :class:`drivers.hazcam.rig.PairRig`)
        exposed together, and when: seconds on the clock the rover runs on (the simulated
        world's for the simulator, epoch seconds for real cameras)."""


BACKENDS: BackendRegistry[HazcamBackend] = BackendRegistry(NAME, HazcamSettings)
