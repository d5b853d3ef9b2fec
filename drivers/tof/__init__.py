"""MESA SwissRanger SR4000 time-of-flight camera: rvs-libtof's interface (seed 000 sect. 4.2).

``create(settings, world)`` builds a :class:`~drivers.tof.device.Tof` over the backend
``settings.backend`` names: ``mesasr`` (ctypes over libMesaSR, a real camera on USB) or ``sim``
(renders the shared simulated world). It is not opened until ``open()``. Backends register in
:data:`BACKENDS`; importing their modules here is their registration.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rvs_params import Settings

from . import mesasr, replay, simulated  # noqa: F401 - registers the backends
from .backend import BACKENDS, Backend, SR4000Settings
from .device import Cancelled, Tof, parse_serial
from .query import find_cameras

__all__ = ["BACKENDS", "PEERS", "Backend", "Cancelled", "SR4000Settings", "Tof", "create", "find_cameras", "parse_serial"]


PEERS: tuple[str, ...] = ()  # built after, and given to create() as, these device kinds


def create(settings: Mapping[str, Any] | Settings | None, world: Any = None) -> Tof:
    """A ToF device for the ``drivers.tof`` settings (a camera alone gets a world of its own)."""
    config = BACKENDS.settings(settings)
    return Tof(config, BACKENDS.create(config, world))
