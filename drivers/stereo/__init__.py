"""The PIKE F-210B stereo pair (rvs-libcam-avt, seed 000 sect. 4.1 and appendix A).

``create(config, world, trigger)`` picks the camera backend from ``config["backend"]``:
``dc1394`` drives the real FireWire cameras through libdc1394, ``sim`` renders the simulated
world. ``trigger`` is the trigger box (an object with ``pulse()`` or a callable) that a stereo
grab fires so both cameras expose at the same instant.
"""

from __future__ import annotations

from typing import Any

from drivers.stereo.errors import GrabCancelled
from drivers.stereo.modes import PIXEL_FORMATS, RESOLUTIONS
from drivers.stereo.pair import StereoPair

BACKENDS = ("sim", "dc1394")


def create(config: dict[str, Any], world: Any = None, trigger: Any = None) -> StereoPair:
    backend = str(config.get("backend", "sim"))
    if backend == "sim":
        from drivers.stereo.sim import SimCameras

        return StereoPair(config, SimCameras(config, world), trigger)
    if backend == "dc1394":
        from drivers.stereo.dc1394 import Dc1394Cameras

        return StereoPair(config, Dc1394Cameras(config), trigger)
    raise ValueError(f"unknown stereo backend {backend!r}; accepted: {', '.join(BACKENDS)}")


__all__ = ["BACKENDS", "PIXEL_FORMATS", "RESOLUTIONS", "GrabCancelled", "StereoPair", "create"]
