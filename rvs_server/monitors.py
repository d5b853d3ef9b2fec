"""Background monitors: loops that use the PTU and a camera between jobs (the hazard monitor of
hazard-start and the target tracker of track3d-start, in ``commands/awareness.py``).

They are threads, not jobs: they run while the GNC drives and while other commands are answered.
The rules they follow (documented in the protocol page):

- **They yield to jobs.** A job holds ``app.device_lock`` for its whole run, a monitor only for
  one cycle at a time; while a job runs (or the server is in standby, sleep, break or fault) the
  monitor pauses without touching a device, then resumes and points the PTU back where it was.
  A job asked for while a monitor runs is therefore accepted as usual (it waits at most one
  monitor cycle for the devices). The hazard monitor says so with ``EVENT kind=hazard
  level=paused``; after the pause its next level is always sent.
- **One holder of the PTU.** The hazard monitor and the tracker both steer the PTU, so starting
  one while the other runs is ``E_BUSY`` naming it.
- **break stops jobs, not monitors**; the monitors pause in the break mode and resume after
  continue/reset. hazard-stop / track3d-stop, quit and server shutdown stop them.
- A device failure inside a monitor puts the server in fault mode as a job's would, and ends the
  monitor with a last EVENT carrying ``code=E_DEVICE``.
- Every log line of a monitor's thread carries the connection, command and tag of the request
  that started it, and the monitor's name.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections import deque
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import structlog

from drivers.base import CALL_CANCEL, DeviceError
from prox_workflows.algorithms.transforms import HeadCalibration

from .bus import tapped_call
from .protocol import Fixed, ProtocolError, Reply

if TYPE_CHECKING:
    from .app import App

log = structlog.get_logger("rvs.awareness")

class Stopped(Exception):
    """The monitor was asked to stop in the middle of a device call."""


class Monitor:
    """A background loop that uses the PTU and a camera between jobs (see the module docstring)."""

    name: ClassVar[str] = "monitor"
    TIMED: ClassVar[int] = 20  # cycles the timing figures cover

    def __init__(self, app: App, period: float, log_context: dict[str, Any] | None = None) -> None:
        self.app = app
        self.period = period
        # conn, command and tag of the request that started it: bound in the monitor's thread
        self.log_context: dict[str, Any] = {**(log_context or {}), "monitor": self.name}
        self.stop_event = threading.Event()
        self.thread = threading.Thread(target=self._run, name=f"rvs-{self.name}", daemon=True)
        self.state = "starting"
        self.cycles = 0
        # (cycle ms without PTU motion, of which ms waiting for the camera) of the timed cycles:
        # the last TIMED of them, never the monitor's first (see timing_fields)
        self.timed: deque[tuple[float, float]] = deque(maxlen=self.TIMED)
        self.starts: deque[float] = deque(maxlen=10)
        self.pointing: tuple[float, float] | None = None  # where the PTU should look (pan, tilt)
        self.error: str | None = None
        self._move_s = 0.0
        self._io_s = 0.0

    # -- life cycle ---------------------------------------------------------------------------
    def start(self) -> None:
        self.thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        """Ask the loop to end and wait for it (blocking: call it off the event loop)."""
        self.stop_event.set()
        if self.thread.is_alive() and threading.current_thread() is not self.thread:
            self.thread.join(timeout)
        if self.state != "failed":
            self.state = "stopped"

    def _pause_reason(self) -> dict[str, Any] | None:
        job = self.app.jobs.current
        if job is not None:
            return {"reason": "job", "job": job.id}
        if self.app.mode_blocks_devices():
            return {"reason": self.app.base_mode}
        return None

    def _run(self) -> None:
        with structlog.contextvars.bound_contextvars(**self.log_context):
            self._loop()

    def _loop(self) -> None:
        app = self.app
        log.info("monitor_start", monitor=self.name, period=self.period)
        try:
            while not self.stop_event.is_set():
                reason = self._pause_reason()
                if reason is not None:
                    if self.state != "paused":
                        self.state = "paused"
                        self.on_pause(reason)
                    self.stop_event.wait(0.02)
                    continue
                if not app.device_lock.acquire(timeout=0.1):
                    continue
                try:
                    if self._pause_reason() is not None or self.stop_event.is_set():
                        continue
                    resumed = self.state == "paused"
                    self.state = "running"
                    if resumed:
                        self.on_resume()
                    started = time.monotonic()
                    self.starts.append(started)
                    self._move_s = self._io_s = 0.0
                    self.cycle()
                    spent = time.monotonic() - started
                    if self.cycles:  # the first cycle warms the camera's and the kernels' caches
                        self.timed.append((1000.0 * max(0.0, spent - self._move_s), 1000.0 * self._io_s))
                    self.cycles += 1
                finally:
                    app.device_lock.release()
                self.stop_event.wait(max(0.0, self.period - (time.monotonic() - started)))
        except Stopped:
            pass
        except DeviceError as exc:
            if not self.stop_event.is_set():
                self._fail(exc, device=exc.device)
        except Exception as exc:  # noqa: BLE001 - a monitor bug must end the monitor, not the server
            if not self.stop_event.is_set():
                log.exception("monitor_failed", monitor=self.name)
                self._fail(exc)
        log.info("monitor_end", monitor=self.name, cycles=self.cycles, state=self.state)

    def _fail(self, exc: Exception, device: str | None = None) -> None:
        self.state = "failed"
        self.error = str(exc)
        app = self.app

        def on_loop() -> None:
            app.monitors.discard(self)
            fields: dict[str, Any]
            if device is not None:
                app.device_failed(device, exc.message)  # type: ignore[attr-defined]
                fields = {"code": "E_DEVICE", "device": device,
                          "message": f"{exc}; the {self.name} monitor stopped, send reset to recover"}
            else:
                fields = {"code": "E_INTERNAL", "message": f"{type(exc).__name__}: {exc}; the {self.name} "
                                                          "monitor stopped (logged)"}
            app.broadcast(Reply("RVS", "EVENT", {**self.failure_fields(), **fields}))
            app.announce_mode()

        app.loop.call_soon_threadsafe(on_loop)

    # -- device helpers -----------------------------------------------------------------------
    def call(self, fn: Any, *args: Any, **kwargs: Any) -> Any:
        """A driver call that a stop interrupts (the cancel event of a job, for a monitor)."""
        t0 = time.monotonic()
        token = CALL_CANCEL.set(self.stop_event)
        try:
            return tapped_call(self.app.bus, fn, *args, cancel=self.stop_event, **kwargs)
        except Exception:
            if self.stop_event.is_set():
                raise Stopped() from None
            raise
        finally:
            CALL_CANCEL.reset(token)
            self._io_s += time.monotonic() - t0

    def point(self, pan: float, tilt: float, tolerance: float = 0.05) -> tuple[float, float]:
        """Move the PTU unless it is there already; the motion's time is not cycle time."""
        self.pointing = (pan, tilt)
        here = self.app.ptu_position()
        if here is not None and abs(here[0] - pan) <= tolerance and abs(here[1] - tilt) <= tolerance:
            return here
        t0 = time.monotonic()
        reached = self.call(self.app.devices.get("ptu").move, pan, tilt, True)
        dt = time.monotonic() - t0
        self._move_s += dt
        self._io_s -= dt
        return float(reached[0]), float(reached[1])

    def intervals(self) -> list[float]:
        """Start-to-start times of the last few cycles."""
        return list(np.diff(self.starts)) if len(self.starts) > 1 else []

    def rate(self) -> float:
        """Cycles per second over the last few cycles."""
        if len(self.starts) < 2:
            return 0.0
        span = self.starts[-1] - self.starts[0]
        return (len(self.starts) - 1) / span if span > 0 else 0.0

    def head(self) -> HeadCalibration:
        return HeadCalibration.from_dict(self.app.config.get("head").as_dict())

    def emit(self, fields: dict[str, Any]) -> None:
        self.app.broadcast_threadsafe(Reply("RVS", "EVENT", fields))

    def timing_fields(self) -> dict[str, Any]:
        """Mean and longest cycle, and mean camera wait, all over one set of cycles: the last
        TIMED, leaving out the first, which warms caches and would make a mean above the
        maximum; ``timed_cycles`` says how many there are (0: only the first has run)."""
        timed = list(self.timed)
        ms = [cycle for cycle, _ in timed]
        io = [wait for _, wait in timed]
        return {"cycle_ms": Fixed(float(np.mean(ms)) if ms else 0.0, 1),
                "cycle_ms_max": Fixed(max(ms, default=0.0), 1),
                "grab_ms": Fixed(float(np.mean(io)) if io else 0.0, 1),
                "timed_cycles": len(timed)}

    # -- what a concrete monitor fills in -----------------------------------------------------
    def cycle(self) -> None:
        raise NotImplementedError(f"{type(self).__name__} must say what one cycle does")

    def on_pause(self, reason: dict[str, Any]) -> None:
        pass

    def on_resume(self) -> None:
        """After a pause the PTU is wherever the job left it: point it back."""
        if self.pointing is not None:
            self.point(*self.pointing)

    def status_fields(self) -> dict[str, Any]:
        raise NotImplementedError(f"{type(self).__name__} must say what status shows of it")

    def shown_state(self) -> str:
        """The state as status shows it: paused as soon as a job or a mode calls for it, not
        only once the monitor's thread has noticed at its next cycle."""
        if self.state == "running" and self._pause_reason():
            return "paused"
        return self.state

    def failure_fields(self) -> dict[str, Any]:
        raise NotImplementedError(f"{type(self).__name__} must say what its failure EVENT carries")


# What the PTU-holder refusal calls each monitor and how it is stopped.
_TITLES = {"hazard": ("the hazard monitor", "hazard-stop"), "track": ("the target tracker", "track3d-stop")}


class Monitors:
    """The running monitors by name (``hazard``, ``track``).

    Started, stopped and dropped on the event loop only (a failing monitor hands its removal to
    the loop), so it needs no lock; ``stop_all`` at shutdown runs once nothing starts any more."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._running: dict[str, Monitor] = {}

    def __contains__(self, name: object) -> bool:
        return name in self._running

    def __getitem__(self, name: str) -> Monitor:
        return self._running[name]

    def __iter__(self) -> Iterator[Monitor]:
        return iter(list(self._running.values()))

    def __len__(self) -> int:
        return len(self._running)

    def get(self, name: str) -> Monitor | None:
        return self._running.get(name)

    def refuse_other_holder(self, wanted: str) -> None:
        """E_BUSY if another PTU-steering monitor than ``wanted`` runs."""
        for name, monitor in self._running.items():
            if name != wanted:
                what, stop = _TITLES.get(name, (name, "stop it"))
                raise ProtocolError("E_BUSY", f"{what} is running and holds the PTU; send {stop} first "
                                              f"({monitor.state}, {monitor.cycles} cycles)")

    def start(self, monitor: Monitor) -> None:
        self._running[monitor.name] = monitor
        monitor.start()

    async def stop(self, name: str) -> Monitor | None:
        """Stop the named monitor and wait for its thread off the loop; None if none ran."""
        monitor = self._running.pop(name, None)
        if monitor is not None:
            await self._loop.run_in_executor(None, monitor.stop)
        return monitor

    def discard(self, monitor: Monitor) -> None:
        """Forget a monitor that ended by itself (it failed), unless a new one took its name."""
        if self._running.get(monitor.name) is monitor:
            del self._running[monitor.name]

    def stop_all(self) -> None:
        """Stop every monitor and wait for its thread (server shutdown; blocking)."""
        for monitor in list(self._running.values()):
            monitor.stop()
        self._running.clear()

    def status_fields(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for monitor in list(self._running.values()):
            out.update(monitor.status_fields())
        return out
