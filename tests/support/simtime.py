"""Simulated time for the server's monitors (the hazard monitor and the target tracker).

The monitors are threads that cycle as fast as the machine lets them (or every -period s) while
the world they watch moves on: in real time, what a monitor sees and reports depends on how fast
the machine is (on a loaded one a cycle takes longer, the target walks farther between two
frames, a one-second window holds fewer cycles). The tests of what the monitors report run
them in simulated time instead, one ToF frame at a time:

- the monitors' clock (``time`` as ``rvs_server.monitors`` and ``rvs_server.commands.awareness``
  see it) and the time stamp
  of the poses the GNC reports (``rvs_server.app.Pose``) read a simulated clock;
- each ToF frame first waits at a gate until the test lets simulated time run past it
  (:meth:`SimTime.run`), then ``on_frame(t)`` puts the world where it is at ``t`` (the test
  moves the target, the rover, hides things), then the frame is taken; the clock then moves on
  by ``frame`` seconds, so a cycle lasts exactly that long however long the machine took.

A run is thus the same, frame for frame, on any machine. While the monitor waits at the gate,
every EVENT of the frames before has been handed to the event loop, so a request sent then is
answered after them (:meth:`SimTime.sync`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import pytest

import rvs_server.app as app_module
import rvs_server.monitors as monitors_module
from rvs_server.commands import awareness

WAIT = 120.0  # s: a safety net for a monitor that never comes to the gate (a hang), not a speed bound


class SimClock:
    """``monotonic()`` and ``time()`` of simulated time, frame ``k`` at ``start + k * frame``
    (counted in frames, so a thousand frames do not add up rounding errors)."""

    def __init__(self, frame: float, start: float = 1000.0, epoch: float = 1_800_000_000.0) -> None:
        self.frame = frame
        self.start = start
        self.epoch = epoch
        self.k = 0

    @property
    def t(self) -> float:
        return self.start + self.k * self.frame

    def monotonic(self) -> float:
        return self.t

    def time(self) -> float:
        return self.epoch + self.t


class SimTime:
    """The gate between a monitor's ToF frames (see the module docstring)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, app: Any, frame: float,
                 on_frame: Callable[[float], None] | None = None) -> None:
        self.clock = SimClock(frame)
        self.on_frame = on_frame
        self._cond = threading.Condition()
        self._limit = 0  # frames with k < limit may be taken
        self._waiting = False
        self._closed = False
        clock, real_pose = self.clock, app_module.Pose
        monkeypatch.setattr(awareness, "time", clock)
        monkeypatch.setattr(monitors_module, "time", clock)
        monkeypatch.setattr(app_module, "Pose", lambda *a, **kw: real_pose(*a, **{"time": clock.time(), **kw}))
        tof = app.devices.get("tof")
        self._grab_xyz = tof.grab_xyz
        monkeypatch.setattr(tof, "grab_xyz", self._grab)

    @property
    def t(self) -> float:
        """The simulated time of the next frame."""
        return self.clock.t

    def scene(self, wall: str | float) -> float:
        """The simulated time of an EVENT's ``time`` field."""
        return float(wall) - self.clock.epoch

    def _grab(self, integrate: int = 1, confidence: float = 0.0, cancel: Any = None) -> Any:
        def stopped() -> bool:
            return self._closed or (cancel is not None and cancel.is_set())

        with self._cond:
            while self.clock.k >= self._limit and not stopped():
                self._waiting = True
                self._cond.notify_all()
                self._cond.wait(0.05)
            self._waiting = False
        if stopped():  # the monitor is being stopped: the grab sees its cancel and ends the cycle
            return self._grab_xyz(integrate, confidence, cancel)
        if self.on_frame is not None:
            self.on_frame(self.clock.t)
        try:
            return self._grab_xyz(integrate, confidence, cancel)
        finally:
            with self._cond:
                self.clock.k += 1
                self._cond.notify_all()

    def run(self, frames: int = 1) -> None:
        """Let ``frames`` more frames be taken and wait until the monitor is back at the gate."""
        with self._cond:
            self._limit = self.clock.k + frames
            self._cond.notify_all()
            if not self._cond.wait_for(lambda: self._waiting and self.clock.k >= self._limit, WAIT):
                raise AssertionError(f"the monitor did not take frame {self._limit} (at {self.clock.k})")

    def run_until(self, t: float) -> None:
        """Take every frame before simulated time ``t``."""
        self.run(max(0, round((t - self.clock.t) / self.clock.frame + 0.4999)))

    def sync(self, client: Any, kind: str) -> tuple[list[dict[str, str]], dict[str, str]]:
        """The EVENTs of ``kind`` sent for the frames taken so far, and a status reply after them."""
        client.send("status")
        lines = client.until_final(timeout=WAIT)
        events = [r.fields for r in lines if r.status == "EVENT" and r.fields.get("kind") == kind]
        return events, lines[-1].fields

    def close(self) -> None:
        """Open the gate for good (teardown: a monitor still running must not hang there)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
