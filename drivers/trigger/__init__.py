"""The JR LPT trigger box (seed 000 sect. 4.1.5): one pulse on pin 2 fires both PIKE cameras.

``create(config, world)`` picks the backend from ``config["backend"]``: ``ppdev`` drives a real
parallel port through /dev/parportN, ``sim`` pulses the simulated world's trigger bus.
"""

from __future__ import annotations

from typing import Any

from drivers.trigger.device import TriggerBase

BACKENDS = ("sim", "ppdev")


def create(config: dict[str, Any], world: Any = None) -> TriggerBase:
    backend = str(config.get("backend", "sim"))
    if backend == "sim":
        from drivers.trigger.sim import SimTrigger

        return SimTrigger(config, world)
    if backend == "ppdev":
        from drivers.trigger.ppdev import PpdevTrigger

        return PpdevTrigger(config)
    raise ValueError(f"unknown trigger backend {backend!r}; accepted: {', '.join(BACKENDS)}")


__all__ = ["BACKENDS", "TriggerBase", "create"]
