"""Backends by name, per device kind, as pyserial picks a port class from a URL scheme.

Each device package keeps one :class:`BackendRegistry` and marks its backend classes with
``@BACKENDS.backend("sim")``. A backend class declares its settings (``settings``, a
:class:`~rvs_params.Settings` dataclass), its optional capabilities and, for a simulator,
the faults it can inject; the registry composes the device's settings class from the front
end's and every registered backend's, so ``config/drivers.yaml``, ``--set`` and
``config -set`` accept exactly the keys some backend reads.

:data:`DEVICE_KINDS` is the one list of device kinds the server builds, checks, resets and
re-initialises; :func:`open_order` puts each kind after the peers its package declares
(``PEERS``: the stereo pair needs the trigger box that fires it).
"""

from __future__ import annotations

import dataclasses
import enum
import importlib
from collections.abc import Callable, Mapping
from typing import Any, ClassVar, Generic, Protocol, TypeVar

from drivers.base import DeviceError
from rvs_params import Settings, param

DEVICE_KINDS: tuple[str, ...] = ("ptu", "tof", "stereo", "trigger", "rover", "hazcam")


class Capability(enum.StrEnum):
    """Optional features a backend may have; the front end asks instead of probing attributes."""

    FAULTS = "faults"  # inject_fault(kind): a simulator's failure modes
    LINK_CHECK = "link_check"  # check_link(): prove the USB/bus link without a full grab
    TRUTH = "truth"  # the simulated world's ground truth (calibration, effective exposure)


class UnknownBackend(DeviceError, ValueError):
    """A configured backend no module registered; the message lists the registered ones.

    A DeviceError (the device cannot be built: E_DEVICE) and a ValueError (a bad setting), so
    callers of either kind catch it; whatever package the device is, this is the one type.
    """

    def __init__(self, device: str, name: str, known: list[str]) -> None:
        super().__init__(device, f"unknown backend {name!r} for drivers.{device}.backend; "
                                 f"registered: {', '.join(known)}")
        self.backend = name
        self.known = known


class BackendClass(Protocol):
    """What the registry reads from a registered class (its instances are the device's Backend)."""

    name: ClassVar[str]
    settings: ClassVar[type[Settings]]
    capabilities: ClassVar[frozenset[Capability]]
    faults: ClassVar[tuple[str, ...]]


B = TypeVar("B")


class BackendRegistry(Generic[B]):
    """The backends of one device kind and the settings class they compose."""

    def __init__(self, device: str, front: type[Settings], default: str = "sim") -> None:
        """``front`` declares the keys of the device's front end (shared by all its backends)."""
        self.device = device
        self.front = front
        self.default = default
        self._classes: dict[str, type[B]] = {}
        self._settings_cls: type[Settings] | None = None

    def backend(self, name: str) -> Callable[[type[B]], type[B]]:
        """Class decorator: register ``cls`` as backend ``name`` of this device."""

        def register(cls: type[B]) -> type[B]:
            if name in self._classes:
                raise ValueError(f"{self.device} backend {name!r} registered twice")
            cls.name = name  # type: ignore[attr-defined]
            for attr, empty in (("settings", _NoSettings), ("capabilities", frozenset()), ("faults", ())):
                if not any(attr in vars(k) for k in cls.__mro__):
                    setattr(cls, attr, empty)
            self._classes[name] = cls
            self._settings_cls = None
            return cls

        return register

    def names(self) -> list[str]:
        """The registered backends, the default (the simulator) first, then as registered."""
        return sorted(self._classes, key=lambda n: n != self.default)

    def get(self, name: str) -> type[B]:
        try:
            return self._classes[name]
        except KeyError:
            raise UnknownBackend(self.device, name, self.names()) from None

    def settings_class(self) -> type[Settings]:
        """The device's settings: the front end's keys plus every registered backend's.

        All backends' keys are accepted whatever backend is chosen, as one drivers.yaml holds
        the simulator's model next to the real camera's library path.
        """
        if self._settings_cls is not None:
            return self._settings_cls
        bases = [self.front] + [c.settings for c in self._classes.values()]  # type: ignore[attr-defined]
        unique = list(dict.fromkeys(b for b in bases if b is not _NoSettings))
        backend = ("backend", str, param(self.default, f"{self.device} backend",
                                         choices=tuple(self.names())))
        cls = dataclasses.make_dataclass(f"{self.device.capitalize()}Settings", [backend],
                                         bases=tuple(reversed(unique)))
        cls.__doc__ = f"drivers.{self.device}: the front end's and every backend's settings."
        cls.__module__ = self.front.__module__
        self._settings_cls = cls
        return cls

    def settings(self, data: Mapping[str, Any] | Settings | None = None) -> Any:
        """Typed settings from a mapping (a console's YAML, a test's dict) or a settings object."""
        name = data.get("backend") if isinstance(data, Mapping) else None
        if name is not None and name not in self._classes:
            raise UnknownBackend(self.device, str(name), self.names())
        return self.settings_class().from_mapping(data, where=f"drivers.{self.device}")

    def create(self, settings: Any, *args: Any, **kwargs: Any) -> B:
        """The backend ``settings.backend`` names, built from the settings (not opened)."""
        return self.get(settings.backend)(settings, *args, **kwargs)


@dataclasses.dataclass
class _NoSettings(Settings):
    """A backend that reads nothing beyond the front end's keys."""


def registry(kind: str) -> BackendRegistry[Any]:
    """The registry of device ``kind`` (importing its package registers its backends)."""
    if kind not in DEVICE_KINDS:
        raise ValueError(f"no device kind {kind!r}; kinds: {', '.join(DEVICE_KINDS)}")
    return importlib.import_module(f"drivers.{kind}").BACKENDS


def peers(kind: str) -> tuple[str, ...]:
    """The kinds a device of ``kind`` is given at creation (its package's ``PEERS``)."""
    registry(kind)  # the kind check
    return tuple(importlib.import_module(f"drivers.{kind}").PEERS)


def inputs(kind: str) -> tuple[str, ...]:
    """What else of the server's a device of ``kind`` is given at creation, by name (its
    package's ``INPUTS``: the rover gets the pose feed its GNC reports into)."""
    registry(kind)  # the kind check
    return tuple(getattr(importlib.import_module(f"drivers.{kind}"), "INPUTS", ()))


def open_order() -> list[str]:
    """DEVICE_KINDS with every kind after its peers (a device is built with its peers open)."""
    order: list[str] = []

    def visit(kind: str, path: tuple[str, ...]) -> None:
        if kind in order:
            return
        if kind in path:
            raise ValueError(f"device peers form a cycle: {' -> '.join(path + (kind,))}")
        for peer in peers(kind):
            visit(peer, path + (kind,))
        order.append(kind)

    for kind in DEVICE_KINDS:
        visit(kind, ())
    return order


def fault_kinds() -> dict[str, tuple[str, ...]]:
    """Per device kind whose simulator declares faults, those faults (what ``sim fault`` offers)."""
    out: dict[str, tuple[str, ...]] = {}
    for kind in DEVICE_KINDS:
        reg = registry(kind)
        faults = tuple(reg.get("sim").faults) if "sim" in reg.names() else ()  # type: ignore[attr-defined]
        if faults:
            out[kind] = faults
    return out
