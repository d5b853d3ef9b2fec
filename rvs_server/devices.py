"""The device registry: builds the configured devices and answers for their health.

Backends are chosen per device in ``config/drivers.yaml``; the registry only knows the device
kinds (drivers.registry.DEVICE_KINDS) and the ``create(settings, world)`` factory each driver
package exposes, as pyusb's core only knows its backend protocol.

The registry reads the live ``drivers`` configuration (the config store's object, which
``config -set`` changes) every time it builds a device, and remembers the settings each device
was built from: a device whose settings changed since is built anew at its next reinit or reset,
and one that takes some keys while open (its ``reconfigure``: the keys declared live) gets
them at once.
"""

from __future__ import annotations

import copy
import functools
import importlib
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
import structlog

from drivers.base import Cancel, Device, DeviceError, DeviceInterrupted
from drivers.registry import inputs, open_order, peers
from prox_workflows.algorithms.stereo import cloud, disparity
from rvs_params import Settings

log = structlog.get_logger("rvs.devices")


def stereo_points(left: np.ndarray, right: np.ndarray, calibration: Any, params: Any) -> tuple[np.ndarray, np.ndarray]:
    """The workflows' stereo matcher as a device that matches its own pairs takes it (the hazcams'
    ``matcher``): the matched points in the left camera's frame and their left pixels."""
    points, _, pixels = cloud(disparity(left, right, calibration, params))
    return points, pixels


@functools.cache
def _factory(name: str) -> Callable[..., Device]:
    return importlib.import_module(f"drivers.{name}").create


class DeviceRegistry:
    """Open devices by name, with the error of each one that failed to open or check."""

    def __init__(self, drivers: Any, world: Any = None, **given: Any) -> None:
        """``drivers`` is the live DriversConfig (one typed settings section per device kind), never
        a copy: ``config -set`` replaces a section there, and the next build reads it. ``given``:
        what a device package asks for besides the world (its ``INPUTS``, e.g. ``poses``)."""
        self.drivers = drivers
        self.world = world
        self.given = given
        self.devices: dict[str, Device] = {}
        self.errors: dict[str, str] = {}
        self.built: dict[str, Settings] = {}  # per device: the settings it runs with
        self.lock = threading.RLock()

    def section(self, name: str) -> Any:
        """A device's settings as they are now (a copy: a device must not see later edits)."""
        return copy.deepcopy(vars(self.drivers)[name])

    @property
    def names(self) -> list[str]:
        """The device kinds, in the order they are opened (each after its peers)."""
        return open_order()

    def pending(self) -> list[str]:
        """``device.key`` of every drivers value that waits for its device's reinit or reset."""
        out: list[str] = []
        for name in self.names:
            built = self.built.get(name)
            if built is not None:
                out += [f"{name}.{k}" for k in sorted(self.section(name).changed(built))]
        return out

    def reconfigure(self) -> None:
        """Give each open device the keys of its changed section that it can take while open.

        Runs on the event loop, with no job running (config -set refuses drivers changes then);
        a ToF grab of a background monitor may hold the camera for one grab meanwhile. A value a
        device refuses raises ValueError before that device changes; a device that fails while
        taking a value keeps it pending, for the reinit or reset that failure calls for anyway.
        """
        with self.lock:
            for name, dev in self.devices.items():
                live = self.section(name)
                if not live.changed(self.built.get(name)):
                    continue
                try:
                    taken = dev.reconfigure(live)
                except ValueError as exc:
                    raise ValueError(f"drivers.{name}: {exc}") from None
                except DeviceError as exc:
                    log.warning("device_reconfigure_failed", device=name, error=exc.message)
                    continue
                if taken:
                    now = live.as_dict()
                    built = self.built[name]
                    self.built[name] = type(built).from_mapping({**built.as_dict(), **{k: now[k] for k in taken}})
                log.info("device_reconfigured", device=name, keys=",".join(taken) or "none")

    def _stale(self, name: str) -> bool:
        return bool(self.section(name).changed(self.built.get(name)))

    def _create(self, name: str) -> Device:
        create = _factory(name)
        kwargs = {peer: self.devices[peer] for peer in peers(name) if peer in self.devices}
        kwargs.update({key: self.given[key] for key in inputs(name) if key in self.given})
        section = self.section(name)
        self.built[name] = copy.deepcopy(section)
        return create(section, self.world, **kwargs)

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
            for other, device in self.devices.items():  # e.g. the cameras fire the new trigger box
                if name in peers(other):
                    device.attach(name, dev)  # type: ignore[attr-defined]
            log.info("device_open", device=name, backend=dev.backend)

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
        """Re-initialise each device; one whose section changed since it was built is rebuilt."""
        first: DeviceError | None = None
        for name in names or self.names:
            try:
                if name in self.devices and not self._stale(name):
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

    def reset(self, name: str, cancel: Cancel = None) -> None:
        """Reset one device (reopen it if its reset fails); rebuilt if its section changed. A
        reset that ``cancel`` stopped is not reopened: the break it belongs to ends the job."""
        dev = self.devices.get(name)
        if dev is not None and not self._stale(name):
            try:
                dev.reset(cancel)
                self.errors.pop(name, None)
                return
            except DeviceInterrupted:
                raise
            except Exception:  # noqa: BLE001 - fall back to reopening the device
                pass
        self.open(name)

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
