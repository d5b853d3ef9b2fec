"""The device registry: builds the configured devices and answers for their health.

Backends are chosen per device in ``config/drivers.yaml``; the registry only knows the
``create(config, world)`` factory each driver package exposes, as pyusb's core only knows its
backend protocol.
"""

from __future__ import annotations

import functools
import importlib
import threading
from typing import Any

import structlog

from drivers.base import Device, DeviceError

log = structlog.get_logger("rvs.devices")

DEVICE_NAMES = ("ptu", "tof", "trigger", "stereo")  # the trigger box first: the cameras fire it


@functools.cache
def _factory(name: str) -> Any:
    module = importlib.import_module(f"drivers.{name}")
    return getattr(module, "create", None)


class DeviceRegistry:
    """Open devices by name, with the error of each one that failed to open or check."""

    def __init__(self, drivers_config: dict[str, dict[str, Any]], world: Any = None) -> None:
        self.config = drivers_config
        self.world = world
        self.devices: dict[str, Device] = {}
        self.errors: dict[str, str] = {}
        self.lock = threading.RLock()

    @property
    def names(self) -> list[str]:
        """Devices that have a driver in this build, in a fixed order."""
        return [n for n in DEVICE_NAMES if n in self.config and _factory(n) is not None]

    def uses_sim(self) -> bool:
        return any(self.config.get(n, {}).get("backend") == "sim" for n in DEVICE_NAMES)

    def _create(self, name: str) -> Device:
        create = _factory(name)
        kwargs: dict[str, Any] = {}
        if name == "stereo" and "trigger" in self.devices:
            kwargs["trigger"] = self.devices["trigger"]
        return create(dict(self.config[name]), self.world, **kwargs)

    def open(self, name: str) -> None:
        """(Re)open one device; a failure is kept as its error and raised."""
        with self.lock:
            old = self.devices.pop(name, None)
            if old is not None:
                try:
                    old.close()
                except Exception as exc:  # noqa: BLE001 - closing a broken device must not stop reopening
                    log.warning("device_close_failed", device=name, error=str(exc))
            try:
                dev = self._create(name)
                dev.open()
            except DeviceError as exc:
                self.errors[name] = exc.message
                raise
            except Exception as exc:  # noqa: BLE001 - any driver failure is a device failure here
                self.errors[name] = f"{type(exc).__name__}: {exc}"
                raise DeviceError(name, self.errors[name]) from exc
            self.devices[name] = dev
            self.errors.pop(name, None)
            log.info("device_open", device=name, backend=getattr(dev, "backend", "?"))

    def open_all(self) -> dict[str, str]:
        """Open every configured device; failures are reported, not raised (server start)."""
        for name in self.names:
            try:
                self.open(name)
            except DeviceError as exc:
                log.error("device_open_failed", device=name, error=exc.message)
        return self.summary()

    def get(self, name: str) -> Any:
        dev = self.devices.get(name)
        if dev is None:
            why = self.errors.get(name, "not configured in this build")
            raise DeviceError(name, f"not available ({why}); fix it and send reinit -device {name}")
        return dev

    def check(self, names: list[str] | None = None) -> dict[str, str]:
        """Ask each device to answer; the first failure is raised after all were tried."""
        first: DeviceError | None = None
        for name in names or self.names:
            try:
                dev = self.get(name)
                dev.check()
                self.errors.pop(name, None)
            except DeviceError as exc:
                self.errors[name] = exc.message
                first = first or exc
        if first is not None:
            raise first
        return self.summary()

    def reinit(self, names: list[str] | None = None) -> dict[str, str]:
        first: DeviceError | None = None
        for name in names or self.names:
            try:
                if name in self.devices:
                    self.devices[name].reinit()
                    self.errors.pop(name, None)
                else:
                    self.open(name)
            except DeviceError as exc:
                self.errors[name] = exc.message
                first = first or exc
        if first is not None:
            raise first
        return self.summary()

    def healthy(self) -> bool:
        return not self.errors

    def summary(self) -> dict[str, str]:
        return {n: ("error" if n in self.errors else "ok" if n in self.devices else "closed") for n in self.names}

    def status(self) -> dict[str, dict[str, Any]]:
        out: dict[str, dict[str, Any]] = {}
        for name in self.names:
            dev = self.devices.get(name)
            if dev is None:
                out[name] = {"state": "error", "error": self.errors.get(name, "closed")}
                continue
            try:
                out[name] = {"state": "error" if name in self.errors else "ok", **dev.status()}
            except Exception as exc:  # noqa: BLE001 - status must never fail
                out[name] = {"state": "error", "error": str(exc)}
        return out

    def close(self) -> None:
        with self.lock:
            for name, dev in list(self.devices.items()):
                try:
                    dev.close()
                except Exception as exc:  # noqa: BLE001
                    log.warning("device_close_failed", device=name, error=str(exc))
            self.devices.clear()
