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

# PIKE F-210B limits (AVT PIKE technical manual): shutter 1 us .. 67 s, gain 0 .. 22 dB,
# white balance registers 10 bit, auto-exposure target 8 bit.
SHUTTER_US = (1, 67_000_000)
GAIN_DB = (0.0, 22.0)
WHITE_BALANCE = (0, 1023)
TARGET_GREY = (1, 254)


@dataclass(frozen=True)
class CameraSettings:
    shutter_us: int = 8000
    gain_db: float = 0.0
    white_balance: tuple[int, int] = (512, 512)  # (U/B, V/R) register values; 512 = unity in the sim
    target_grey: int = 128  # auto-exposure target grey level
    auto_exposure: bool = False  # shutter follows target_grey instead of shutter_us

    def __post_init__(self) -> None:
        self._check()

    def _check(self) -> None:
        def within(name: str, value: float, bounds: tuple[float, float]) -> None:
            if not bounds[0] <= value <= bounds[1]:
                raise ValueError(f"{name} must be in [{bounds[0]}, {bounds[1]}], got {value}")

        within("shutter_us", self.shutter_us, SHUTTER_US)
        within("gain_db", self.gain_db, GAIN_DB)
        if len(self.white_balance) != 2:
            raise ValueError(f"white_balance must be two values (U/B, V/R), got {self.white_balance!r}")
        for value in self.white_balance:
            within("white_balance", value, WHITE_BALANCE)
        within("target_grey", self.target_grey, TARGET_GREY)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CameraSettings:
        return cls().replace(**data)

    def replace(self, **changes: Any) -> CameraSettings:
        """A copy with ``changes`` applied, coerced and validated (ValueError on a bad key or value)."""
        names = [f.name for f in dataclasses.fields(self)]
        unknown = sorted(set(changes) - set(names))
        if unknown:
            raise ValueError(f"unknown camera setting(s) {', '.join(unknown)}; accepted: {', '.join(names)}")
        values = dataclasses.asdict(self)
        for key, raw in changes.items():
            try:
                values[key] = _coerce(key, raw)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"bad value for {key}: {raw!r} ({exc})") from None
        return CameraSettings(**values)

    def to_dict(self) -> dict[str, Any]:
        data = dataclasses.asdict(self)
        data["white_balance"] = list(self.white_balance)
        return data


def _coerce(key: str, raw: Any) -> Any:
    if key == "white_balance":
        if isinstance(raw, str):
            raw = raw.replace(",", " ").split()
        return tuple(int(v) for v in raw)
    if key == "auto_exposure":
        if isinstance(raw, str):
            lowered = raw.strip().lower()
            if lowered not in ("1", "0", "true", "false", "on", "off", "yes", "no"):
                raise ValueError("expected true/false")
            return lowered in ("1", "true", "on", "yes")
        return bool(raw)
    if key == "gain_db":
        return float(raw)
    value = float(raw)
    if value != int(value):
        raise ValueError("expected an integer")
    return int(value)


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
