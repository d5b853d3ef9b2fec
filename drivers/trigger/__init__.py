"""The JR LPT trigger box (seed 000 sect. 4.1.5): one pulse on pin 2 fires both PIKE cameras.

``create(settings, world)`` builds a :class:`Trigger` over the backend ``settings.backend``
names: ``ppdev`` drives a real parallel port through /dev/parportN, ``sim`` pulses the
simulated world's trigger bus. Backends register themselves in :data:`BACKENDS`; importing
their modules here is their registration.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from drivers.trigger import ppdev, replay, sim  # noqa: F401 - registers the backends
from drivers.trigger.backend import BACKENDS, TriggerBackend, TriggerSettings
from drivers.trigger.device import Trigger
from rvs_params import Settings

PEERS: tuple[str, ...] = ()  # built after, and given to create() as, these device kinds


def create(settings: Mapping[str, Any] | Settings | None, world: Any = None) -> Trigger:
    """The trigger box for the ``drivers.trigger`` settings; not opened yet."""
    return Trigger(settings, world)


__all__ = ["BACKENDS", "PEERS", "Trigger", "TriggerBackend", "TriggerSettings", "create"]
