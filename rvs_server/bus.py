"""The server's one publish point: what happens in it (wire lines, events, new maps, sensor
frames), for whoever watches the whole server rather than one connection (the Foxglove server,
an MCAP recording).

Emitters call :meth:`Bus.publish` from wherever the thing happens (the event loop, a job's
thread, a monitor's thread) and pay one tuple read when nobody watches. A subscriber is called
in the emitter's thread and must only take the item and return (queue it): the event loop and
the jobs never wait for a watcher's encoding or file writes.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

# Item kinds and what their ``data`` holds:
#   request  conn (id), line (bytes as received)
#   reply    conn (id), reply (protocol.Reply), job (bool: a line of a job, not an immediate reply): every
#            line but EVENTs, to the connection it was sent to (a TCP client or a console page)
#   event    reply (protocol.Reply): an EVENT, once however many connections get it
#   maps     layers (grid.Layers), name: the current DEM was replaced or restored
#   calling  device, call: a driver call is about to be made (published in the calling thread, which
#            waits for the subscribers: the hub samples the state the call starts from)
#   frame    device, call (the driver method's name), args, result: a driver grab returned
#   bounds   bounds (the see loop's BoundsMap itself, which it goes on fusing into), replan (bool): a
#            frame was fused into it, or a plan is made on it
#   mission  mission (the navigation.mission.Mission itself: its strategy, its loop's maps and timings,
#            its track): a navigate's mission is under way, for what watches it run (tools.bench.scale)
KINDS = ("request", "reply", "event", "maps", "calling", "frame", "bounds", "mission")


@dataclass(frozen=True)
class Item:
    kind: str
    time_ns: int  # wall clock (ns since the epoch) when it happened: an MCAP log time
    data: dict[str, Any] = field(default_factory=dict)


Subscriber = Callable[[Item], None]


class Bus:
    """Fan-out to subscribers; thread-safe (the subscriber tuple is replaced, never edited)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._subscribers: tuple[Subscriber, ...] = ()

    @property
    def watched(self) -> bool:
        """Whether anyone listens: an emitter may skip building an expensive item."""
        return bool(self._subscribers)

    def subscribe(self, fn: Subscriber) -> None:
        with self._lock:
            self._subscribers = (*self._subscribers, fn)

    def unsubscribe(self, fn: Subscriber) -> None:
        # equality, not identity: each ``obj.method`` is a new bound method, equal to the one subscribed
        with self._lock:
            self._subscribers = tuple(s for s in self._subscribers if s != fn)

    def publish(self, kind: str, at: int | None = None, **data: Any) -> None:
        """``at``: when it happened (ns since the epoch), if not now."""
        subscribers = self._subscribers
        if not subscribers:
            return
        item = Item(kind, time.time_ns() if at is None else at, data)
        for fn in subscribers:
            fn(item)


def tapped_call(bus: Bus, fn: Any, *args: Any, **kwargs: Any) -> Any:
    """Call a driver method and publish what it returned as a ``frame`` (the device is the
    method's owner's ``name``); the time is the call's start, when a camera exposes. A
    ``calling`` item goes first, so that the state the call starts from is recorded before it."""
    if not bus.watched:
        return fn(*args, **kwargs)
    owner = getattr(fn, "__self__", None)
    device, call = getattr(owner, "name", "?"), getattr(fn, "__name__", "?")
    bus.publish("calling", device=device, call=call)
    t = time.time_ns()
    result = fn(*args, **kwargs)
    bus.publish("frame", t, device=device, call=call, args=args, result=result)
    return result
