"""A PTU bench for the tests: the emulator on a pty master, the client on the slave path."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from typing import Any

from drivers.ptu.client import PtuClient
from drivers.ptu.emulator import PtuEmulator, open_pty


@contextlib.contextmanager
def bench(
    *, open_client: bool = True, client: dict[str, Any] | None = None, **emulator: Any
) -> Iterator[tuple[PtuEmulator, PtuClient]]:
    master, slave, path = open_pty()
    emulator.setdefault("time_scale", 0.0)
    emu = PtuEmulator(master, **emulator).start()
    opts = {"timeout": 0.5, "move_timeout": 2.0, "reset_timeout": 5.0, **(client or {})}
    ptu = PtuClient(path, 9600, **opts)
    try:
        if open_client:
            ptu.open()
        yield emu, ptu
    finally:
        ptu.close()
        emu.stop()
        os.close(master)
        os.close(slave)
