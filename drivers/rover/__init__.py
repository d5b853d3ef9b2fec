"""The rover's drive: what moves the rover and says where it is (seed 000 sect. 5.4).

``create(settings, world, poses)`` builds a :class:`Rover` over the backend
``settings.backend`` names: ``gnc`` (the rover's GNC drives and reports its pose into the
server's pose feed) or ``sim`` (the server drives the shared simulated world's rover). Backends
register in :data:`BACKENDS`; importing their modules here is their registration.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rvs_params import Settings

from . import gnc, replay, sim  # noqa: F401 - registers the backends
from .backend import (
    BACKENDS,
    Attitude,
    Motion,
    Pilot,
    Pose,
    PoseFeed,
    RoverBackend,
    RoverSettings,
    Settle,
    Silent,
)
from .device import Rover

PEERS: tuple[str, ...] = ()  # built after, and given to create() as, these device kinds
INPUTS: tuple[str, ...] = ("poses",)  # what the server gives create() besides the world


def create(settings: Mapping[str, Any] | Settings | None, world: Any = None, poses: PoseFeed | None = None) -> Rover:
    """The rover for the ``drivers.rover`` settings; not opened yet."""
    return Rover(settings, world, poses)


__all__ = ["BACKENDS", "INPUTS", "PEERS", "Attitude", "Motion", "Pilot", "Pose", "PoseFeed", "Rover", "RoverBackend",
           "RoverSettings", "Settle", "Silent", "create"]
