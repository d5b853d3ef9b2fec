"""The real trigger box: pin 2 (data bit D0) of a PC parallel port through Linux ppdev.

ppdev (``/dev/parportN``) lets a user program drive the port without root I/O-port access:
claim the port, write the data register, release it. The pulse is D0 high for ``pulse_us`` then
low again; the low write and the release sit in ``finally`` blocks so a failed or interrupted
pulse never leaves the line high (which would hold the cameras' trigger input asserted).
"""

from __future__ import annotations

import fcntl
import os
import struct
import time
from dataclasses import dataclass
from typing import Any

from drivers.base import DeviceError
from drivers.trigger import ioctl
from drivers.trigger.backend import BACKENDS, TriggerSettings
from drivers.trigger.errors import port_error
from rvs_params import Settings, param

PIN2 = 0x01  # D0 is pin 2 of the DB-25 connector


def _byte(value: int) -> bytes:
    return struct.pack("B", value)


@dataclass
class PpdevSettings(Settings):
    exclusive: bool = param(True, "PPEXCL before claiming, so a port held by lp fails loudly (EBUSY)")


@BACKENDS.backend("ppdev")
class PpdevTrigger:
    settings = PpdevSettings

    def __init__(self, settings: TriggerSettings | PpdevSettings, world: Any = None) -> None:
        self.path = settings.device  # type: ignore[union-attr]
        self.exclusive = settings.exclusive  # type: ignore[union-attr]
        self._fd: int | None = None

    def open(self) -> None:
        if self._fd is not None:
            return
        try:
            fd = os.open(self.path, os.O_RDWR)
        except OSError as exc:
            raise port_error(exc, self.path, "opening the trigger port") from exc
        try:
            if self.exclusive:
                # Exclusive claims fail with EBUSY while lp holds the port instead of silently sharing it.
                fcntl.ioctl(fd, ioctl.PPEXCL)
            # Prove the port can be claimed now, so a busy port is reported at open, not at the first grab.
            self._claim(fd)
            try:
                fcntl.ioctl(fd, ioctl.PPWDATA, _byte(0))
            except OSError as exc:
                raise port_error(exc, self.path, "writing the trigger port") from exc
            finally:
                self._release(fd)
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd

    def close(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)

    def check(self) -> None:
        assert self._fd is not None
        self._claim(self._fd)
        self._release(self._fd)

    def _claim(self, fd: int) -> None:
        try:
            fcntl.ioctl(fd, ioctl.PPCLAIM)
        except OSError as exc:
            raise port_error(exc, self.path, "claiming the trigger port") from exc

    def _release(self, fd: int) -> None:
        try:
            fcntl.ioctl(fd, ioctl.PPRELEASE)
        except OSError as exc:
            raise port_error(exc, self.path, "releasing the trigger port") from exc

    def fire(self, pulse_us: float) -> None:
        fd = self._fd
        if fd is None:
            raise DeviceError("trigger", "trigger port is not open")
        self._claim(fd)
        try:
            try:
                fcntl.ioctl(fd, ioctl.PPWDATA, _byte(PIN2))
                time.sleep(pulse_us / 1e6)
            except OSError as exc:
                raise port_error(exc, self.path, "raising pin 2") from exc
            finally:
                try:
                    fcntl.ioctl(fd, ioctl.PPWDATA, _byte(0))
                except OSError as exc:
                    raise port_error(exc, self.path, "lowering pin 2") from exc
        finally:
            self._release(fd)

    def status(self) -> dict[str, Any]:
        return {"device": self.path}

    def inject_fault(self, kind: str | None) -> None:
        raise DeviceError("trigger", "a real trigger port has no simulated faults")
