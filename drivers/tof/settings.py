"""The camera settings rvs-libtof kept in a settings file (sect. 4.2.3-4.2.7 of seed 000).

One dataclass holds everything SetSettings, SetColorRange, SetImgCorrectModes and
SetEnhancedXyz change, so that SaveSettings/LoadSettings is a YAML dump and load of it. The
defaults come from the typed drivers.tof settings (their ``live`` keys, declared in
:class:`drivers.tof.backend.SR4000Settings`); a settings file, when configured, overrides them and
is created from them when it does not exist (rvs-libtof's CreateDefaultSettingsFile).
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from rvs_params import Settings

from . import constants as k
from .backend import BACKENDS, SR4000Settings

# Per image type: the value range that maps onto the colour (or grey) scale; None = min..max.
DEFAULT_COLOUR_RANGE: dict[str, list[float] | None] = {
    "distance": None,
    "amplitude": None,
    "confidence": [0.0, 1.0],
    "z": None,
}


# The drivers.tof keys that are camera settings (declared live in SR4000Settings): a running
# server applies a change of them to the open camera at once (Tof.reconfigure); the other keys
# only take effect in a new device.
CAMERA_KEYS = tuple(name for name, spec in SR4000Settings.specs().items() if spec.live)


@dataclass
class AutoExposure:
    """SR_SetAutoExposure's parameters; MESA's suggested SR4000 values are 1, 150, 5, 70."""

    min_integration: int = 1
    max_integration: int = 150
    percent_over: int = 5
    desired: int = 70

    def validate(self) -> AutoExposure:
        integration = SR4000Settings.specs()["integration"]  # the same register as the camera's own
        self.min_integration = integration.coerce(self.min_integration, "auto exposure min_integration")
        self.max_integration = integration.coerce(self.max_integration, "auto exposure max_integration")
        if self.min_integration > self.max_integration:
            raise ValueError("auto exposure: min_integration must not exceed max_integration")
        if not 0 <= int(self.percent_over) <= 100:
            raise ValueError(f"auto exposure: percent_over {self.percent_over} outside 0..100")
        if not 0 <= int(self.desired) <= 255:
            raise ValueError(f"auto exposure: desired {self.desired} outside 0..255")
        return self


@dataclass
class TofSettings:
    amplitude_threshold: int = 0
    modulation_mhz: float = 30.0
    integration: int = 30
    auto_exposure: bool = False
    auto_exposure_params: AutoExposure = field(default_factory=AutoExposure)
    auto_exposure_max_iterations: int = 20
    corrections: dict[str, bool] = field(
        default_factory=lambda: {name: name in k.DEFAULT_CORRECTIONS for name in k.CORRECTION_FLAGS}
    )
    enhanced_xyz: bool = False
    undistort: bool = True
    colour_range: dict[str, list[float] | None] = field(default_factory=lambda: dict(DEFAULT_COLOUR_RANGE))

    def validate(self) -> TofSettings:
        """Each key typed and range-checked by its drivers.tof declaration; then what a declaration
        cannot say: the frequencies the SR4000 takes, the correction modes, the colour ranges."""
        specs = SR4000Settings.specs()
        for name in _DECLARED:
            setattr(self, name, specs[name].coerce(getattr(self, name), "ToF settings"))
        self.modulation_mhz = k.check_frequency(self.modulation_mhz)
        self.auto_exposure_params.validate()
        unknown = set(self.corrections) - set(k.CORRECTION_FLAGS)
        if unknown:
            raise ValueError(f"unknown correction mode(s) {sorted(unknown)}; known: {sorted(k.CORRECTION_FLAGS)}")
        full = {name: False for name in k.CORRECTION_FLAGS}
        full.update({name: _as_bool(v, name) for name, v in self.corrections.items()})
        self.corrections = full
        ranges = dict(DEFAULT_COLOUR_RANGE)
        for image_type, rng in (self.colour_range or {}).items():
            ranges[check_colour_type(image_type)] = check_colour_range(rng)
        self.colour_range = ranges
        return self

    def mode(self, base: int = int(k.AcquireMode.AM_SW_TRIGGER)) -> int:
        """The SR_SetMode value: correction flags and enhanced XYZ over the trigger bits of base."""
        return k.modes_from_corrections(self.corrections, self.enhanced_xyz, base)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TofSettings:
        data = dict(data or {})
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown ToF setting(s) {sorted(unknown)}; known: {sorted(known)}")
        ae = data.pop("auto_exposure_params", None) or {}
        if isinstance(ae, AutoExposure):
            ae = dataclasses.asdict(ae)
        ae_known = {f.name for f in dataclasses.fields(AutoExposure)}
        if set(ae) - ae_known:
            raise ValueError(f"unknown auto exposure parameter(s) {sorted(set(ae) - ae_known)}")
        settings = cls(**data, auto_exposure_params=AutoExposure(**{n: int(v) for n, v in ae.items()}))
        return settings.validate()

    @classmethod
    def from_config(cls, config: Settings | Mapping[str, Any]) -> TofSettings:
        """Defaults from the drivers.tof settings (their live keys); a mapping is typed first."""
        values = (config if isinstance(config, Settings) else BACKENDS.settings(config)).as_dict()
        data: dict[str, Any] = {}
        for key in CAMERA_KEYS:
            if key != "corrections" and values[key] is not None:
                data[key] = values[key]
        corrections = values["corrections"]
        if corrections is not None:
            if isinstance(corrections, dict):
                data["corrections"] = dict(corrections)
            else:  # a list of the enabled modes
                names = list(corrections)
                unknown = set(names) - set(k.CORRECTION_FLAGS)
                if unknown:
                    raise ValueError(f"unknown correction mode(s) {sorted(unknown)}")
                data["corrections"] = {name: name in names for name in k.CORRECTION_FLAGS}
        return cls.from_dict(data)

    def copy(self) -> TofSettings:
        return TofSettings.from_dict(self.to_dict())


# the keys whose SR4000Settings declaration (type, range) is the whole check
_DECLARED = ("amplitude_threshold", "modulation_mhz", "integration", "auto_exposure", "auto_exposure_max_iterations",
             "enhanced_xyz", "undistort")


def check_colour_type(image_type: str) -> str:
    if image_type not in DEFAULT_COLOUR_RANGE:
        raise ValueError(f"colour range image type {image_type!r} not one of {sorted(DEFAULT_COLOUR_RANGE)}")
    return image_type


def check_colour_range(rng: Any) -> list[float] | None:
    if rng is None:
        return None
    try:
        low, high = (float(v) for v in rng)
    except (TypeError, ValueError):
        raise ValueError(f"colour range must be [low, high] or null, got {rng!r}") from None
    if not high > low:
        raise ValueError(f"colour range needs low < high, got {low} .. {high}")
    return [low, high]


def _as_bool(value: Any, name: str) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.lower() in ("true", "on", "yes", "1", "false", "off", "no", "0"):
        return value.lower() in ("true", "on", "yes", "1")
    raise ValueError(f"{name} must be true or false, got {value!r}")


def save_settings(settings: TofSettings, path: str | os.PathLike) -> Path:
    """Write the settings as YAML, atomically (a crash never leaves half a settings file)."""
    path = Path(path).expanduser()
    path.parent.mkdir(parents=True, exist_ok=True)
    text = "# SR4000 camera settings (rvs-libtof SaveSettings); load with LoadSettings\n"
    text += yaml.safe_dump(settings.to_dict(), sort_keys=False)
    fd, tmp = tempfile.mkstemp(prefix=path.name, suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def load_settings(path: str | os.PathLike) -> TofSettings:
    path = Path(path).expanduser()
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except FileNotFoundError:
        raise FileNotFoundError(f"ToF settings file {path} does not exist") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"ToF settings file {path} is not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"ToF settings file {path} must hold a mapping")
    return TofSettings.from_dict(data)


def load_or_create(path: str | os.PathLike, defaults: TofSettings) -> tuple[TofSettings, bool]:
    """Load the default settings file, creating it from ``defaults`` when it is missing.

    Returns the settings and whether the file was created.
    """
    path = Path(path).expanduser()
    if not path.exists():
        save_settings(defaults, path)
        return defaults.copy(), True
    return load_settings(path), False
