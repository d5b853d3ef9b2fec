"""The server's event bus: what a subscriber that leaves stops receiving."""

from __future__ import annotations

from typing import Any

from rvs_server.bus import Bus, Item


class Listener:
    def __init__(self) -> None:
        self.kinds: list[str] = []

    def accept(self, item: Item) -> None:
        self.kinds.append(item.kind)


def test_a_bound_method_unsubscribed_by_a_fresh_reference_receives_nothing_more() -> None:
    bus: Any = Bus()
    a, b = Listener(), Listener()
    bus.subscribe(a.accept)
    bus.subscribe(b.accept)
    bus.publish("one")
    bus.unsubscribe(a.accept)  # a new bound-method object, as the hub and the console pass it
    bus.publish("two")
    assert a.kinds == ["one"] and b.kinds == ["one", "two"]
