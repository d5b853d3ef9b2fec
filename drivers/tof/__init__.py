"""MESA SwissRanger SR4000 time-of-flight camera: rvs-libtof's interface (seed 000 sect. 4.2).

``create(config, world)`` picks the backend from ``config["backend"]``: ``mesasr`` (ctypes over
libMesaSR, a real camera on USB) or ``sim`` (renders the shared simulated world). Both return a
:class:`~drivers.tof.device.Tof`; it is not opened until ``open()``.
"""

from __future__ import annotations

from typing import Any

from drivers.base import DeviceError

from .device import Cancelled, Tof, parse_serial
from .query import find_cameras

__all__ = ["BACKENDS", "Cancelled", "Tof", "create", "find_cameras", "parse_serial"]

BACKENDS = ("sim", "mesasr")


def create(config: dict[str, Any], world: Any = None) -> Tof:
    """A ToF device for the ``tof`` section of config/drivers.yaml."""
    backend = config.get("backend", "sim")
    if backend == "sim":
        from .simulated import SimTof

        if world is None:
            world = _default_world(config)
        return Tof(config, SimTof(config, world))
    if backend == "mesasr":
        from .mesasr import MesaSR

        return Tof(config, MesaSR(config))
    raise DeviceError("tof", f"unknown backend {backend!r}: drivers.tof.backend must be one of {', '.join(BACKENDS)}")


def _default_world(config: dict[str, Any]) -> Any:
    """A world of its own for a simulated camera used outside the server (consoles, scripts)."""
    try:
        from drivers.sim.world import World
    except ImportError as exc:
        raise DeviceError("tof", f"simulated backend needs drivers.sim ({exc})") from None
    return World.from_scene(config.get("scene", "office"), seed=int(config.get("seed", 0) or 0))
