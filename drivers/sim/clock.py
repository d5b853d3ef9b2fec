"""The simulated world's one clock: the rover's drive, the PTU's moves and the ToF's frames all
take their durations on it, so a mission's time is the same whatever the machine or the speed-up.

``scale`` is simulated seconds per wall second: 1 real time, 10 ten times faster, 0 instant
(a ``sleep`` returns at once and moves the clock on by its duration). With ``scale > 0`` the
clock runs with the wall clock; with 0 it moves only when something sleeps on it, so tests can
drive a rover for minutes of simulated time in milliseconds and still read the right times.

What moved an instant clock on is kept by name (``spent``: the rover driving, turning on the
spot or reversing, the PTU's moves awaited, each sensor's frames taken standing), so a mission's
time can be told apart: where it went, not only how long it took.

The scale may be given as a callable (the server passes the ``sim`` config module's value), so
``config -module sim -set time_scale=...`` takes effect at once: the clock rebases at the
instant it notices the change and never jumps.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable

__all__ = ["SimClock"]

ScaleSource = float | Callable[[], float]


class SimClock:
    """now(), sleep(dt) and advance_to(t) of simulated time; thread-safe."""

    def __init__(self, scale: ScaleSource = 1.0, start: float = 0.0) -> None:
        self._source = scale
        self._lock = threading.Lock()
        self._scale = self._read_scale()
        self._sim_ref = float(start)
        self._wall_ref = time.monotonic()
        # simulated seconds by what moved the clock on (advance_to's ``what``): at scale 0 all of
        # the clock's time; at scale > 0 the wall moves it, and this holds only its jumps
        self.spent: Counter[str] = Counter()

    def _read_scale(self) -> float:
        value = float(self._source() if callable(self._source) else self._source)
        if value < 0:
            raise ValueError("the simulated clock's time_scale must be >= 0 (0 = instant)")
        return value

    def _sync(self) -> float:
        """The simulated time now (caller holds the lock); rebases when the scale changed."""
        wall = time.monotonic()
        now = self._sim_ref + (wall - self._wall_ref) * self._scale
        scale = self._read_scale()
        if scale != self._scale:
            self._sim_ref, self._wall_ref, self._scale = now, wall, scale
        return now

    @property
    def scale(self) -> float:
        """Simulated seconds per wall second (0: instant)."""
        with self._lock:
            self._sync()
            return self._scale

    def now(self) -> float:
        """Simulated seconds since the world was made."""
        with self._lock:
            return self._sync()

    def advance_to(self, t: float, what: str = "other") -> None:
        """Move the clock on to ``t`` if it is behind (instant mode: something took that long);
        ``what`` took it (``spent``). Overlapping waits count once: the later end moves it on."""
        with self._lock:
            now = self._sync()
            if t > now:
                self._sim_ref += t - now
                self.spent[what] += t - now

    def sleep(self, dt: float, cancel: Callable[[], bool] | None = None, what: str = "other") -> bool:
        """Let ``dt`` simulated seconds pass: ``dt / scale`` wall seconds, or none at scale 0.

        Returns False if ``cancel()`` turned true first (checked about every 20 ms of wall time);
        the clock has then moved on only as far as the wall clock took it.
        """
        if dt <= 0:
            return not (cancel is not None and cancel())
        with self._lock:
            start = self._sync()
            scale = self._scale
        if scale == 0:
            self.advance_to(start + dt, what)
            return not (cancel is not None and cancel())
        end = start + dt
        while True:
            if cancel is not None and cancel():
                return False
            left = end - self.now()
            if left <= 0:
                return True
            scale = self.scale
            if scale == 0:  # switched to instant meanwhile
                self.advance_to(end, what)
                return True
            time.sleep(min(left / scale, 0.02))
