"""The simulated trigger box pulses the world's trigger bus; its faults read like the real port's."""

from __future__ import annotations

import threading

import pytest

from drivers.base import DeviceError
from drivers.sim.trigger import TriggerBus
from drivers.trigger import Trigger, create
from drivers.trigger.sim import SimTrigger

Bus = TriggerBus  # the world contract's bus, as the simulated world has it


class World:
    def __init__(self) -> None:
        self.trigger = Bus()


def make(world: object = None) -> Trigger:
    dev = create({"backend": "sim", "device": "/dev/parport0", "pulse_us": 100}, world)
    assert isinstance(dev.port, SimTrigger)
    dev.open()
    return dev


def test_pulse_wakes_a_waiting_camera() -> None:
    world = World()
    dev = make(world)
    after = world.trigger.count
    got: list[int | None] = []
    waiter = threading.Thread(target=lambda: got.append(world.trigger.wait_for_pulse(after, 5.0)))
    waiter.start()
    assert dev.pulse() == 1
    waiter.join(5.0)
    assert got == [after + 1]
    assert dev() == 2  # a trigger is also a plain callable
    assert world.trigger.count == 2
    assert dev.status()["bus_count"] == 2


@pytest.mark.parametrize(("kind", "needle"), [("busy", "rmmod lp"), ("missing", "modprobe ppdev"), ("denied", "lp group")])
def test_faults_block_the_pulse_and_clear(kind: str, needle: str) -> None:
    world = World()
    dev = make(world)
    dev.inject_fault(kind)
    with pytest.raises(DeviceError) as info:
        dev.pulse()
    assert info.value.device == "trigger"
    assert needle in info.value.message
    assert world.trigger.count == 0
    assert dev.status()["last_error"] == info.value.message
    with pytest.raises(DeviceError):
        dev.check()
    dev.inject_fault(None)
    dev.reinit()
    assert dev.pulse() == 1
    assert world.trigger.count == 1


def test_busy_port_fails_at_open() -> None:
    dev = create({"backend": "sim"}, World())
    dev.inject_fault("busy")
    with pytest.raises(DeviceError, match="busy"):
        dev.open()
    assert dev.status()["open"] is False


def test_unknown_fault_is_a_usage_error() -> None:
    with pytest.raises(ValueError, match="busy"):
        make(World()).inject_fault("melted")


def test_without_a_world_the_box_still_counts() -> None:
    dev = make(None)
    assert dev.pulse() == 1
    assert dev.status()["bus_count"] is None


def test_the_shared_world_trigger_bus() -> None:
    from drivers.sim.world import World

    world = World.from_scene("office", seed=0)
    dev = make(world)
    after = world.trigger.count
    assert dev.pulse() == 1
    assert world.trigger.wait_for_pulse(after, 0.0) == after + 1
