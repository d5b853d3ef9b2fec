"""Body hazard cameras: a wide-angle stereo pair at each end of the rover's body, as MER and MSL
carry (seed 000 sect. 2), for the ground the wheels meet next, which the mast cannot see.

``create(settings, world, matcher)`` builds a :class:`Hazcam` over the backend
``settings.backend`` names: ``sim`` renders the shared simulated world, ``dc1394`` drives real
FireWire cameras through the stereo pair's libdc1394 binding. ``matcher`` turns a pair into
points (:data:`StereoMatcher`; the server gives the workflows' stereo matcher). The pairs are
off unless ``drivers.hazcam.cameras`` names them. Backends register in :data:`BACKENDS`;
importing their modules here is their registration.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rvs_params import Settings

from . import dc1394, replay, sim  # noqa: F401 - registers the backends
from .backend import BACKENDS, CAMERAS, HazcamBackend, HazcamSettings
from .device import Hazcam, HazcamFrame, StereoMatcher
from .rig import PairRig, pair_rig

PEERS: tuple[str, ...] = ()  # built after, and given to create() as, these device kinds
INPUTS: tuple[str, ...] = ("matcher",)  # what the server gives create() besides the world


def create(settings: Mapping[str, Any] | Settings | None, world: Any = None,
           matcher: StereoMatcher | None = None) -> Hazcam:
    """The hazard cameras for the ``drivers.hazcam`` settings; not opened yet."""
    config = BACKENDS.settings(settings)
    return Hazcam(config, BACKENDS.create(config, world), matcher)


__all__ = ["BACKENDS", "CAMERAS", "INPUTS", "PEERS", "Hazcam", "HazcamBackend", "HazcamFrame", "HazcamSettings",
           "PairRig", "StereoMatcher", "create", "pair_rig"]
