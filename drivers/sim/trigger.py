"""The simulated trigger line: the LPT box pulses it, the simulated cameras wait on it."""

from __future__ import annotations

import threading
import time


class TriggerBus:
    """A pulse counter with waiters, so cameras capture on the same pulse (the same instant)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._count = 0

    def pulse(self) -> int:
        with self._cond:
            self._count += 1
            self._cond.notify_all()
            return self._count

    @property
    def count(self) -> int:
        with self._cond:
            return self._count

    def wait_for_pulse(self, after: int, timeout: float) -> int | None:
        """Block until the count exceeds ``after``; the new count, or None after ``timeout`` s."""
        deadline = time.monotonic() + max(timeout, 0.0)
        with self._cond:
            while self._count <= after:
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(left)
            return self._count
