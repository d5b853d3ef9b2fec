"""The PIKE F-210B stereo pair (rvs-libcam-avt, seed 000 sect. 4.1 and appendix A).

``create(settings, world, trigger)`` builds a :class:`StereoPair` over the camera backend
``settings.backend`` names: ``dc1394`` drives the real FireWire cameras through libdc1394,
``sim`` renders the simulated world. ``trigger`` is the trigger box (an object with ``pulse()``
or a callable) that a stereo grab fires so both cameras expose at the same instant. Backends
register in :data:`BACKENDS`; importing their modules here is their registration.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from drivers.stereo import dc1394, replay, sim  # noqa: F401 - registers the backends
from drivers.stereo.backend import BACKENDS, CameraBackend, StereoSettings
from drivers.stereo.errors import GrabCancelled
from drivers.stereo.modes import PIXEL_FORMATS, RESOLUTIONS
from drivers.stereo.pair import StereoPair
from rvs_params import Settings

PEERS: tuple[str, ...] = ("trigger",)  # built after, and given to create() as, these device kinds


def create(settings: Mapping[str, Any] | Settings | None, world: Any = None, trigger: Any = None) -> StereoPair:
    """The stereo pair for the ``drivers.stereo`` settings; not opened yet."""
    config = BACKENDS.settings(settings)
    return StereoPair(config, BACKENDS.create(config, world), trigger)


__all__ = ["BACKENDS", "PEERS", "PIXEL_FORMATS", "RESOLUTIONS", "CameraBackend", "GrabCancelled", "StereoPair",
           "StereoSettings", "create"]
