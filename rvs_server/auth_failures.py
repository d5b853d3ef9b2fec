"""Wrong tokens by client address, so that the wait before an ``auth`` answer (commands/system.py)
follows the guesser and not its connection: a new connection from the same address, TCP or
console page, starts where the last one left off.

The table is bounded (``server.auth_addresses``, the address whose last wrong token is oldest
goes first) and forgets an address after ``server.auth_forget`` seconds without a wrong token
from it, so neither many addresses nor a long uptime grow it. Event loop only.
"""

from __future__ import annotations

import asyncio
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass
class Guesses:
    """One address's wrong tokens since its last right one, the time of the last, and the lock
    its auths take in turn (so parallel connections from it cannot guess side by side)."""

    failures: int = 0
    last: float = 0.0
    turn: asyncio.Lock = field(default_factory=asyncio.Lock)


class AuthFailures:
    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._table: OrderedDict[str, Guesses] = OrderedDict()  # the oldest wrong token first

    def of(self, address: str, forget_after: float) -> Guesses | None:
        """The address's record, None when it sent no wrong token within ``forget_after`` s."""
        now = self._clock()
        while self._table:
            oldest = next(iter(self._table.values()))
            if now - oldest.last <= forget_after:
                break
            self._table.popitem(last=False)
        return self._table.get(address)

    def failed(self, address: str, size: int) -> int:
        """Count a wrong token from ``address``; its failures so far. The table keeps ``size``
        addresses at most."""
        entry = self._table.pop(address, None) or Guesses()
        entry.failures += 1
        entry.last = self._clock()
        self._table[address] = entry
        while len(self._table) > size:
            self._table.popitem(last=False)
        return entry.failures

    def clear(self, address: str) -> None:
        """A right token from ``address``: it starts again without a wait."""
        self._table.pop(address, None)

    def __len__(self) -> int:
        return len(self._table)
