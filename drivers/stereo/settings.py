"""Per-camera acquisition settings (RvsCam_Get/Set/Load/SaveSettings) and their YAML file.

Each camera of the pair has its own settings, as in the thesis. The file also stores the target
grey level, which the UniAPI's own save function silently dropped (seed 000 sect. 4.1.4).
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from drivers.stereo.modes import SIDES, check_side
from rvs_params import Settings, param


@dataclass
class CameraKeys(Settings):
    """The keys each camera of the pair is set by, declared once with the PIKE F-210B's limits
    (AVT PIKE technical manual: shutter 1 us .. 67 s, gain 0 .. 22 dB, white balance registers
    10 bit, auto-exposure target 8 bit). The drivers.stereo settings lend them as the power-up
    values; :class:`CameraSettings` checks every change by them."""

    shutter_us: int = param(8000, "exposure time", unit="us", min=1, max=67_000_000)
    gain_db: float = param(0.0, "gain", unit="dB", min=0.0, max=22.0)
    white_balance: list[int] = param([512, 512], "IIDC U/B, V/R registers (rgb8 only; 512 = unity in the sim)",
                                     min=0, max=1023, length=2)
    target_grey: int = param(128, "auto-exposure target grey level", min=1, max=254)
    auto_exposure: bool = param(False, "true: the shutter follows target_grey")


def camera_key(name: str) -> Any:
    """A field declaring camera key ``name`` as :class:`CameraKeys` does, for a settings class that
    lends it (the drivers.stereo settings)."""
    spec = CameraKeys.specs()[name]
    return param(spec.default, spec.help, unit=spec.unit, min=spec.min, max=spec.max, length=spec.length)


_DEFAULTS = CameraKeys()


@dataclass(frozen=True)
class CameraSettings:
    """One camera's settings as a value: what the pair holds per side and writes to its file."""

    shutter_us: int = _DEFAULTS.shutter_us
    gain_db: float = _DEFAULTS.gain_db
    white_balance: tuple[int, int] = tuple(_DEFAULTS.white_balance)  # (U/B, V/R) register values
    target_grey: int = _DEFAULTS.target_grey
    auto_exposure: bool = _DEFAULTS.auto_exposure

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CameraSettings:
        return cls().replace(**data)

    def replace(self, **changes: Any) -> CameraSettings:
        """A copy with ``changes`` applied, each typed and checked by its :class:`CameraKeys`
        declaration (ValueError on a bad key or value)."""
        specs = CameraKeys.specs()
        unknown = sorted(set(changes) - set(specs))
        if unknown:
            raise ValueError(f"unknown camera setting(s) {', '.join(unknown)}; accepted: {', '.join(specs)}")
        values = dataclasses.asdict(self)
        for key, raw in changes.items():
            if key == "white_balance" and isinstance(raw, str):
                raw = ",".join(raw.replace(",", " ").split())  # "500 520" as the console splits it
            value = specs[key].coerce(raw, "camera setting")
            values[key] = tuple(value) if key == "white_balance" else value
        return CameraSettings(**values)

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["white_balance"] = list(self.white_balance)
        return data


def defaults_from_config(config: Any) -> CameraSettings:
    """The power-up settings from the typed drivers.stereo settings (their camera keys)."""
    values = config.as_dict()
    return CameraSettings().replace(**{f.name: values[f.name] for f in dataclasses.fields(CameraSettings)})


def save_settings_file(path: str | os.PathLike[str], settings: dict[str, CameraSettings]) -> Path:
    """Write both cameras' settings atomically (a crash never leaves half a file)."""
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    doc = {"format": "rvs-cam-settings/1"}
    doc.update({side: settings[side].to_dict() for side in SIDES if side in settings})
    fd, tmp = tempfile.mkstemp(prefix=target.name, suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w") as handle:
            yaml.safe_dump(doc, handle, sort_keys=False)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return target


def load_settings_file(
    path: str | os.PathLike[str], current: dict[str, CameraSettings]
) -> dict[str, CameraSettings]:
    """Read a settings file; keys it lacks keep their ``current`` values. ValueError on bad content."""
    source = Path(path)
    try:
        doc = yaml.safe_load(source.read_text())
    except FileNotFoundError:
        raise ValueError(f"settings file {source} does not exist") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"settings file {source} is not valid YAML: {exc}") from None
    if not isinstance(doc, dict):
        raise ValueError(f"settings file {source} must hold a mapping with 'left' and/or 'right'")
    result = dict(current)
    sides = [k for k in doc if k in SIDES]
    if not sides:
        raise ValueError(f"settings file {source} has neither 'left' nor 'right' settings")
    for side in sides:
        section = doc[check_side(side)] or {}
        if not isinstance(section, dict):
            raise ValueError(f"settings file {source}: '{side}' must be a mapping")
        result[side] = current[side].replace(**section)
    return result
