"""The SR4000 camera object of rvs-libtof (seed 000 sect. 4.2), over any backend.

Everything that is not a register call lives here, once: loading and saving settings, the
auto-exposure settling loop, integrating N frames while discarding pixels below a confidence
threshold, XYZ images with -1 for undefined points, undistortion and fake colouring.

Threading: one re-entrant lock serialises every camera operation (a grab holds it for all its
frames). The status snapshot has its own small lock, like rvs-libtof's mutexed status
structure, so a second thread (the server's event loop) reads status while a grab runs.

Pixel rules for grabs: a frame's pixel is used when its distance code is non-zero (the camera
zeroes pixels below the amplitude threshold), its confidence is above 0 (0 = saturated or no
signal) and at least the requested confidence (0..1, the confidence map scaled from 0xFFFF).
The result is the mean over the frames in which the pixel was used; a pixel never used is
undefined: NaN in distance, amplitude and Z images, -1 in all three channels of an XYZ image.
Distances are averaged on the phase circle, so a pixel whose frames straddle the wrap at
c / (2 f) does not average to the middle of the range.
"""

from __future__ import annotations

import contextlib
import copy
import math
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from drivers.base import Cancel, DeviceError
from drivers.registry import Capability

from . import constants as k
from .backend import Backend, DeviceInfo, SR4000Settings
from .colour import fake_colour
from .settings import (
    CAMERA_KEYS,
    TofSettings,
    check_colour_range,
    check_colour_type,
    load_or_create,
    load_settings,
    save_settings,
)

MAX_INTEGRATE = 1000


class Cancelled(Exception):
    """A grab stopped because its cancel event was set (or its cancel callable returned true)."""


def parse_serial(value: Any) -> int:
    """A serial number from config or a prompt: an int, or text read as hex (as printed on the
    camera, e.g. 00-00-40-00-00-2F or 0x4000002F); 0 means the first camera found."""
    if isinstance(value, bool):
        raise ValueError(f"serial number must be an integer or hex text, got {value!r}")
    if isinstance(value, int):
        serial = value
    else:
        text = str(value).strip().lower().replace("-", "").replace(":", "")
        try:
            serial = int(text, 16)
        except ValueError:
            raise ValueError(f"serial number {value!r} is not hex (e.g. 0x4000002F) or 0 for the first camera") from None
    if not 0 <= serial <= 0xFFFFFFFF:
        raise ValueError(f"serial number {value!r} outside 32 bits")
    return serial


COHERENCE = 0.9  # |mean phasor| below this: the frames disagree about the range (wrap boundary)
STRADDLE_M = 0.2  # mean point range this far from the phasor range: some frames wrapped
WRAP_TOLERANCE = 0.25  # share of the unambiguous range two frequencies may disagree by (noise, multipath)


@dataclass
class _Sums:
    """Running per-pixel sums of an integration."""

    phase: np.ndarray  # complex: sum of exp(i * 2 pi * d / rmax) over used frames
    amplitude: np.ndarray
    amplitude_all: np.ndarray
    confidence: np.ndarray
    xyz: np.ndarray
    used: np.ndarray
    frames: int
    rmax: float

    def mean(self, values: np.ndarray, count: np.ndarray) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            return values / count


class Tof:
    """An SR4000 with rvs-libtof's functions; satisfies :class:`drivers.base.Device`."""

    name = "tof"

    def __init__(self, config: SR4000Settings, camera: Backend) -> None:
        """``config``: the typed drivers.tof settings (see drivers.tof.create)."""
        self._config = copy.deepcopy(config)
        self._cam = camera
        self.backend = camera.name
        self.capabilities = camera.capabilities
        self._serial_wanted = parse_serial(config.serial or 0)
        self.settings_file: Path | None = Path(config.settings_file).expanduser() if config.settings_file else None
        self._defaults = TofSettings.from_config(config)
        self._settings = self._defaults.copy()
        self._lock = threading.RLock()
        self._status_lock = threading.Lock()
        self._info: DeviceInfo | None = None
        self._maps: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._K, self._dist = self._calibration()
        self._status: dict[str, Any] = {
            "name": self.name,
            "backend": self.backend,
            "open": False,
            "busy": False,
            "serial": None,
            "trigger_mode": "software",
            "image_type": None,
            "exposure_mode": "manual",
            "exposure_settled": None,
            "modulation_mhz": self._settings.modulation_mhz,
            "range_max_m": round(k.unambiguous_range(self._settings.modulation_mhz), 4),
            "integration": self._settings.integration,
            "integration_ms": round(k.integration_ms(self._settings.integration), 2),
            "amplitude_threshold": self._settings.amplitude_threshold,
            "correction_modes": [],
            "enhanced_xyz": False,
            "undistort": self._settings.undistort,
            "frames": 0,
            "last_error": None,
        }

    # -- Device protocol -------------------------------------------------------------------
    def open(self) -> None:
        """Open the camera by serial (0 = first found) and apply the default settings."""
        with self._lock, self._op(None):
            if not self._cam.is_open:
                self._cam.open(self._serial_wanted)
            self._info = self._cam.info()
            self._apply(self._default_settings())
            self._set_status(open=True, serial=self._info.as_dict()["serial"])

    def close(self) -> None:
        with self._lock:
            try:
                self._cam.close()
            finally:
                self._set_status(open=False, busy=False)

    def status(self) -> dict[str, Any]:
        with self._status_lock:
            snapshot = dict(self._status)
        if Capability.FAULTS in self.capabilities and self._cam.fault is not None:
            snapshot["fault"] = self._cam.fault
        return snapshot

    def check(self) -> dict[str, Any]:
        """Ask the camera for its serial and integration time; DeviceError if it does not answer."""
        with self._lock, self._op(None):
            self._require_open()
            info = self._cam.info()
            integration = self._cam.get_integration()
            return {**info.as_dict(), "integration": integration, "modulation_mhz": self._cam.get_modulation()}

    def reinit(self) -> None:
        """Set the default settings again (rvs-libtof ReInit); reopens a handle lost to a fault."""
        with self._lock:
            if not self._cam.is_open:
                self.open()
                return
            with self._op(None):
                self._apply(self._default_settings())

    def reset(self, cancel: Cancel = None) -> None:
        """Re-activate the camera (close and reopen) and set the default settings."""
        with self._lock:
            with contextlib.suppress(DeviceError):
                self._cam.close()
            self._set_status(open=False)
            self.open()

    def reconfigure(self, config: SR4000Settings) -> list[str]:
        """Take the camera settings (CAMERA_KEYS) of a changed config section while open, so a
        running server changes the modulation frequency without a reinit; returns the keys taken.

        Other keys (backend, serial, calibration, the simulator's model) need a new device. A
        value the camera cannot take is a ValueError before anything changes. With a settings
        file configured, that file (loaded at every open) owns the camera settings: changing
        them here would be lost at the next reinit, so it is a ValueError too. A closed camera
        takes nothing: it gets the values when the server rebuilds it.
        """
        new, old = config.as_dict(), self._config.as_dict()
        changed = [key for key in CAMERA_KEYS if new[key] != old[key]]
        if not changed:
            return []
        if config.settings_file:
            raise ValueError(
                f"drivers.tof.settings_file ({config.settings_file}) holds the camera settings; "
                f"change {', '.join(changed)} there (rvs-tof save) or set settings_file to null first"
            )
        defaults = TofSettings.from_config(config)
        with self._lock:
            if not self._cam.is_open:
                return []
            wanted = defaults.to_dict()
            settings = TofSettings.from_dict({**self._settings.to_dict(), **{key: wanted[key] for key in changed}})
            self._apply_checked(settings)
            self._defaults = defaults
            self._config = type(self._config).from_mapping({**old, **{key: new[key] for key in changed}})
        return changed

    # -- identification --------------------------------------------------------------------
    def query(self) -> dict[str, Any]:
        """Serial, vendor/product ids, manufacturer and product of the open camera."""
        with self._lock, self._op(None):
            self._require_open()
            self._info = self._cam.info()
            return self._info.as_dict()

    @property
    def serial(self) -> int | None:
        return self._info.serial if self._info else None

    def inject_fault(self, kind: str | None, after: int = 0) -> None:
        """Simulated backend only: "unplug", "timeout" or None; see drivers.tof.simulated."""
        if Capability.FAULTS not in self.capabilities:
            raise ValueError(f"faults can only be injected into the simulated ToF, not backend {self.backend!r}")
        self._cam.inject_fault(kind, after)

    # -- settings --------------------------------------------------------------------------
    def get_settings(self) -> TofSettings:
        with self._lock:
            return self._settings.copy()

    def set_settings(
        self,
        amplitude_threshold: int | None = None,
        modulation_mhz: float | None = None,
        integration: int | None = None,
        auto_exposure: bool | None = None,
    ) -> TofSettings:
        """rvs-libtof SetSettings: the basic acquisition settings in one call (None = keep)."""
        with self._lock:
            new = self._settings.copy()
            if amplitude_threshold is not None:
                new.amplitude_threshold = amplitude_threshold
            if modulation_mhz is not None:
                new.modulation_mhz = modulation_mhz
            if integration is not None:
                new.integration = integration
            if auto_exposure is not None:
                new.auto_exposure = auto_exposure
            self._apply_checked(new)
            return self._settings.copy()

    def set_amplitude_threshold(self, value: int) -> None:
        self.set_settings(amplitude_threshold=value)

    def set_modulation(self, frequency_mhz: float) -> None:
        """One of 29, 30, 31, 14.5, 15, 15.5 MHz (the camera is calibrated at 30 MHz)."""
        self.set_settings(modulation_mhz=k.check_frequency(frequency_mhz))

    def set_max_distance(self, metres: float) -> float:
        """Choose the modulation frequency that measures up to ``metres``; returns it (MHz)."""
        frequency = k.frequency_for_distance(metres)
        self.set_settings(modulation_mhz=frequency)
        return frequency

    def set_integration(self, register: int) -> None:
        """Integration register 0..255: 0.3 ms + 0.1 ms per step."""
        self.set_settings(integration=k.check_integration(register))

    def set_integration_ms(self, ms: float) -> int:
        register = k.integration_register(ms)
        self.set_settings(integration=register)
        return register

    def set_auto_exposure(
        self,
        on: bool,
        min_integration: int | None = None,
        max_integration: int | None = None,
        percent_over: int | None = None,
        desired: int | None = None,
        max_iterations: int | None = None,
    ) -> None:
        with self._lock:
            new = self._settings.copy()
            new.auto_exposure = on
            p = new.auto_exposure_params
            for name, value in (
                ("min_integration", min_integration),
                ("max_integration", max_integration),
                ("percent_over", percent_over),
                ("desired", desired),
            ):
                if value is not None:
                    setattr(p, name, int(value))
            if max_iterations is not None:
                new.auto_exposure_max_iterations = int(max_iterations)
            self._apply_checked(new)

    def get_correction_modes(self) -> dict[str, bool]:
        with self._lock:
            return dict(self._settings.corrections)

    def set_correction_modes(self, **modes: bool) -> dict[str, bool]:
        """rvs-libtof SetImgCorrectModes: turn named modes on or off, keep the others.

        Names: fix_pattern, median, denoise_anf, conv_gray, conf_map (AM_COR_FIX_PTRN,
        AM_MEDIAN, AM_DENOISE_ANF, AM_CONV_GRAY, AM_CONF_MAP).
        """
        with self._lock:
            new = self._settings.copy()
            unknown = set(modes) - set(k.CORRECTION_FLAGS)
            if unknown:
                raise ValueError(f"unknown correction mode(s) {sorted(unknown)}; known: {', '.join(k.CORRECTION_FLAGS)}")
            new.corrections.update(modes)
            self._apply_checked(new)
            return dict(self._settings.corrections)

    def get_mode(self) -> int:
        """The AcquireMode bits currently set on the camera."""
        with self._lock, self._op(None):
            self._require_open()
            return self._cam.get_mode()

    def set_enhanced_xyz(self, on: bool) -> None:
        """AM_SHORT_RANGE: a more precise coordinate transform below 1 m."""
        with self._lock:
            new = self._settings.copy()
            new.enhanced_xyz = on
            self._apply_checked(new)

    def get_enhanced_xyz(self) -> bool:
        with self._lock:
            return self._settings.enhanced_xyz

    def set_undistort(self, on: bool) -> None:
        with self._lock:
            new = self._settings.copy()
            new.undistort = on
            self._apply_checked(new)

    def set_colour_range(self, low: float | None, high: float | None, image_type: str = "distance") -> None:
        """Bounds of the colour/grey scale for one image type; None, None = the image's min..max."""
        with self._lock:
            check_colour_type(image_type)
            rng = None if low is None and high is None else check_colour_range([low, high])
            self._settings.colour_range[image_type] = rng

    def get_colour_range(self, image_type: str = "distance") -> list[float] | None:
        with self._lock:
            rng = self._settings.colour_range[check_colour_type(image_type)]
            return list(rng) if rng else None

    def save_settings(self, path: str | Path | None = None) -> Path:
        """Write the current settings (YAML) to ``path`` or the default settings file."""
        with self._lock:
            return save_settings(self._settings, self._settings_path(path))

    def load_settings(self, path: str | Path | None = None) -> TofSettings:
        """Read settings from ``path`` or the default settings file and apply them to the camera."""
        with self._lock:
            settings = load_settings(self._settings_path(path))
            self._apply_checked(settings)
            return settings.copy()

    def create_default_settings_file(self, path: str | Path | None = None) -> Path:
        """Write the built-in defaults (from the driver config) as a settings file."""
        with self._lock:
            return save_settings(self._defaults, self._settings_path(path))

    # -- images ----------------------------------------------------------------------------
    def grab(
        self,
        image_type: str = "distance",
        integrate: int = 1,
        confidence: float = 0.0,
        cancel: Any = None,
        undistort: bool | None = None,
    ) -> np.ndarray:
        """A distance (m), amplitude (counts), confidence (0..1), Z (m) or XYZ image, float32.

        ``integrate`` frames are averaged; pixels below ``confidence`` are discarded (see the
        module docstring). 2-D images are undistorted when ``undistort`` (default: the setting)
        is on; "xyz" returns the H x W x 3 image of :meth:`grab_xyz`, never undistorted.
        """
        if image_type not in k.IMAGE_TYPES:
            raise ValueError(f"image type {image_type!r} not one of {', '.join(k.IMAGE_TYPES)}")
        if image_type == "xyz":
            return self.grab_xyz(integrate, confidence, cancel)[0]
        with self._lock, self._op(image_type):
            sums = self._integrate(integrate, confidence, cancel)
            if image_type == "distance":
                with np.errstate(invalid="ignore"):
                    angle = np.mod(np.angle(sums.phase), 2 * math.pi)
                image = np.where(sums.used > 0, angle / (2 * math.pi) * sums.rmax, np.nan)
            elif image_type == "amplitude":
                image = np.where(sums.used > 0, sums.mean(sums.amplitude, sums.used), np.nan)
            elif image_type == "confidence":
                image = sums.confidence / sums.frames
            else:
                image = np.where(sums.used > 0, sums.mean(sums.xyz[..., 2], sums.used), np.nan)
            image = image.astype(np.float32)
            if self._settings.undistort if undistort is None else undistort:
                image = self.undistort(image)
            return image

    def grab_xyz(self, integrate: int = 1, confidence: float = 0.0, cancel: Any = None,
                 wrap_check: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(xyz, amplitude): H x W x 3 metres in the camera frame (OpenCV: x right, y down,
        z forward), -1 where undefined; and the mean amplitude of all frames (intensity image).

        ``wrap_check``: one more frame at half the modulation frequency (twice the unambiguous
        range, :data:`constants.WRAP_CHECK_FREQUENCY`) and pixels whose two ranges disagree by
        more than ``WRAP_TOLERANCE`` of the unambiguous range are left undefined. A bright wall
        7 m away reads 2 m at 30 MHz, as a phantom floating in the room that the amplitude
        alone cannot tell from a dark rock at grazing incidence (a DEM turns it into a step
        hazard on open floor); at 15 MHz it reads 7 m. Pixels the check frame does not see
        (amplitude below the threshold) are kept."""
        with self._lock, self._op("xyz"):
            sums = self._integrate(integrate, confidence, cancel)
            # A pixel near the unambiguous range reads ~0 in one frame and ~rmax in the next;
            # the mean of such points lands half way, a phantom at rmax/2. Where the frames
            # straddle the wrap like that, the range is the phasor mean (as in the distance
            # image) along the pixel's ray; frames that disagree altogether (phasor coherence
            # below COHERENCE) leave the pixel undefined.
            with np.errstate(invalid="ignore", divide="ignore"):
                coherence = np.abs(sums.phase) / sums.used
                xyz = sums.xyz / sums.used[..., None]
                norm = np.linalg.norm(xyz, axis=2)
                phasor = np.mod(np.angle(sums.phase), 2 * math.pi) / (2 * math.pi) * sums.rmax
                straddle = np.abs(norm - phasor) > STRADDLE_M
                xyz = np.where(straddle[..., None], xyz / norm[..., None] * phasor[..., None], xyz)
            bad = (sums.used == 0) | ~(coherence >= COHERENCE) | ~(norm > 0)
            if wrap_check:
                bad |= self._wrapped(np.linalg.norm(xyz, axis=2), sums.rmax, cancel)
            xyz[bad] = -1.0
            amplitude = sums.amplitude_all / sums.frames
            return xyz.astype(np.float32), amplitude.astype(np.float32)

    def noise_amplitude(self, amplitude: np.ndarray, ranges: np.ndarray) -> tuple[np.ndarray, float]:
        """(amplitude, modulation MHz) the range noise goes with, from an image's ``amplitude`` and
        its pixels' ``ranges`` (m): the phase noise falls as 1 / the returned amplitude, which
        AM_CONV_GRAY hides by scaling the image by (range / reference)^2 (the reference is the
        simulated camera's model's; a real camera's is taken to be the same). The ToF's noise model
        (prox_workflows.algorithms.noise.tof_sigma) takes both."""
        with self._lock:
            gray = bool(self._settings.corrections.get("conv_gray"))
            mhz = float(self._settings.modulation_mhz)
        a = np.asarray(amplitude, dtype=np.float64)
        if gray:
            from .physics import SignalModel

            reference = getattr(self._cam, "model", SignalModel()).conv_gray_reference_m
            a = a / np.maximum(np.asarray(ranges, dtype=np.float64) / reference, 1e-3) ** 2
        return a, mhz

    def _wrapped(self, ranges: np.ndarray, rmax: float, cancel: Any) -> np.ndarray:
        """Pixels whose range ``ranges`` (at the set frequency, unambiguous up to ``rmax``) a
        frame at the check frequency contradicts: the surface lies beyond ``rmax``."""
        check_mhz = k.WRAP_CHECK_FREQUENCY.get(self._settings.modulation_mhz)
        if check_mhz is None:
            return np.zeros(ranges.shape, bool)
        _canceller(cancel)()
        self._cam.set_modulation(check_mhz)
        try:
            frame = self._cam.acquire()
        finally:
            self._cam.set_modulation(self._settings.modulation_mhz)
        self._bump_frames(frame.integration)
        rcheck = k.unambiguous_range(check_mhz)
        seen = frame.distance > 0
        with np.errstate(invalid="ignore"):
            diff = np.mod(frame.distance.astype(np.float64) / k.RAW_MAX * rcheck - ranges, rcheck)
            diff = np.minimum(diff, rcheck - diff)  # around the check frequency's own wrap
            return seen & np.isfinite(ranges) & (diff > WRAP_TOLERANCE * rmax)

    def intrinsics(self) -> tuple[np.ndarray, np.ndarray]:
        """Camera matrix and distortion (k1, k2, p1, p2, k3) used for undistortion."""
        return self._K.copy(), self._dist.copy()

    def undistort(self, image: np.ndarray, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
        """Remove lens distortion from a 2-D image with OpenCV (a copy when there is none)."""
        if not np.any(self._dist):
            return image.copy()
        maps = self._maps.get(interpolation)
        if maps is None:
            h, w = image.shape[:2]
            maps = cv2.initUndistortRectifyMap(self._K, self._dist, None, self._K, (w, h), cv2.CV_32FC1)
            self._maps[interpolation] = maps
        return cv2.remap(image, maps[0], maps[1], interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))

    def fake_colour(self, image: np.ndarray, image_type: str = "distance", mode: str = "jet", order: str = "bgr") -> np.ndarray:
        """A uint8 colour (or grey) preview of an image using this type's colour range."""
        rng = self.get_colour_range(image_type) or [None, None]
        return fake_colour(image, rng[0], rng[1], mode=mode, order=order)

    # -- internals -------------------------------------------------------------------------
    def _calibration(self) -> tuple[np.ndarray, np.ndarray]:
        K, dist = self._cam.intrinsics()
        if self._config.camera_matrix is not None:
            K = np.asarray(self._config.camera_matrix, dtype=np.float64).reshape(3, 3)
        if self._config.distortion is not None:
            d = np.zeros(5)
            given = np.asarray(self._config.distortion, dtype=np.float64).reshape(-1)[:5]
            d[: given.size] = given
            dist = d
        return np.asarray(K, dtype=np.float64), np.asarray(dist, dtype=np.float64)

    def _settings_path(self, path: str | Path | None) -> Path:
        if path is not None:
            return Path(path).expanduser()
        if self.settings_file is None:
            raise ValueError("no settings file given and drivers.tof.settings_file is not configured")
        return self.settings_file

    def _default_settings(self) -> TofSettings:
        if self.settings_file is None:
            return self._defaults.copy()
        try:
            settings, _created = load_or_create(self.settings_file, self._defaults)
        except (OSError, ValueError) as exc:
            raise DeviceError("tof", f"default settings file {self.settings_file}: {exc}") from None
        return settings

    def _require_open(self) -> None:
        if not self._cam.is_open:
            # Let a backend with a fault explain itself (e.g. "disconnected") before the generic text.
            if Capability.LINK_CHECK in self.capabilities:
                self._cam.check_link()
            raise DeviceError("tof", "SR4000 not open; open it, or run reinit/reset after an error")

    def _apply_checked(self, settings: TofSettings) -> None:
        settings = TofSettings.from_dict(settings.to_dict())  # validates
        with self._op(None):
            self._require_open()
            self._apply(settings)

    def _apply(self, settings: TofSettings) -> None:
        """Send settings to the camera; only on success do they become the current ones."""
        cam = self._cam
        cam.set_amplitude_threshold(settings.amplitude_threshold)
        cam.set_modulation(settings.modulation_mhz)
        trigger_bits = cam.get_mode() & int(k.AcquireMode.AM_HW_TRIGGER | k.AcquireMode.AM_SW_TRIGGER)
        cam.set_mode(settings.mode(trigger_bits or int(k.AcquireMode.AM_SW_TRIGGER)))
        p = settings.auto_exposure_params
        if settings.auto_exposure:
            cam.set_auto_exposure(p.min_integration, p.max_integration, p.percent_over, p.desired)
        else:
            cam.set_auto_exposure(0xFF, 0, 0, 0)
        cam.set_integration(settings.integration)
        self._settings = settings.copy()
        mode = cam.get_mode()
        self._set_status(
            trigger_mode=k.trigger_mode_name(mode),
            exposure_mode="auto" if settings.auto_exposure else "manual",
            modulation_mhz=settings.modulation_mhz,
            range_max_m=round(k.unambiguous_range(settings.modulation_mhz), 4),
            integration=settings.integration,
            integration_ms=round(k.integration_ms(settings.integration), 2),
            amplitude_threshold=settings.amplitude_threshold,
            correction_modes=[n for n, on in k.corrections_from_mode(mode).items() if on],
            enhanced_xyz=bool(mode & k.AcquireMode.AM_SHORT_RANGE),
            undistort=settings.undistort,
            # the rest of the camera settings, so a grab's sidecar holds every one it was taken with
            auto_exposure_params=[p.min_integration, p.max_integration, p.percent_over, p.desired],
            auto_exposure_max_iterations=settings.auto_exposure_max_iterations,
            colour_range=[f"{t}:{'auto' if r is None else ','.join(format(v, 'g') for v in r)}"
                          for t, r in settings.colour_range.items()],
        )

    def _set_status(self, **values: Any) -> None:
        with self._status_lock:
            self._status.update(values)

    @contextlib.contextmanager
    def _op(self, image_type: str | None) -> Iterator[None]:
        """Mark the camera busy for the operation and record the error it ends with."""
        values: dict[str, Any] = {"busy": True}
        if image_type is not None:
            values["image_type"] = image_type
        self._set_status(**values)
        try:
            yield
        except DeviceError as exc:
            self._set_status(last_error=str(exc), open=self._cam.is_open)
            raise
        finally:
            self._set_status(busy=False)

    def _settle_exposure(self, cancel: Callable[[], None]) -> None:
        """Acquire (and discard) until the auto-exposed integration time stops changing.

        The camera only updates the integration time on acquisition, so each frame moves it a
        step. It counts as settled when a frame leaves it unchanged, or when it dithers by one
        register step back and forth around its target; the loop gives up after
        ``auto_exposure_max_iterations`` frames (then status says exposure_settled: false).
        """
        previous = self._cam.get_integration()
        last_step = 0
        settled = False
        frames = 0
        for frames in range(1, self._settings.auto_exposure_max_iterations + 1):  # noqa: B007
            cancel()
            frame = self._cam.acquire()
            self._bump_frames(frame.integration)
            current = self._cam.get_integration()
            step = current - previous
            if step == 0 or (abs(step) == 1 and step == -last_step):
                settled = True
                break
            previous, last_step = current, step
        current = self._cam.get_integration()
        self._settings.integration = current
        self._set_status(
            exposure_settled=settled,
            exposure_frames=frames,
            integration=current,
            integration_ms=round(k.integration_ms(current), 2),
        )

    def _integrate(self, integrate: int, confidence: float, cancel: Any) -> _Sums:
        if isinstance(integrate, bool) or int(integrate) != integrate or not 1 <= int(integrate) <= MAX_INTEGRATE:
            raise ValueError(f"integrate must be an integer 1..{MAX_INTEGRATE}, got {integrate!r}")
        confidence = float(confidence)
        if not 0.0 <= confidence <= 1.0:
            raise ValueError(f"confidence threshold {confidence} outside 0..1")
        if confidence > 0 and not self._settings.corrections.get("conf_map"):
            raise ValueError("a confidence threshold needs the confidence map: enable correction mode conf_map")
        self._require_open()
        check_cancel = _canceller(cancel)
        if self._settings.auto_exposure:
            self._settle_exposure(check_cancel)
        rmax = k.unambiguous_range(self._settings.modulation_mhz)
        shape = (self._cam.rows, self._cam.cols)
        sums = _Sums(
            phase=np.zeros(shape, np.complex128),
            amplitude=np.zeros(shape),
            amplitude_all=np.zeros(shape),
            confidence=np.zeros(shape),
            xyz=np.zeros((*shape, 3)),
            used=np.zeros(shape, np.int32),
            frames=0,
            rmax=rmax,
        )
        threshold_code = confidence * k.RAW_MAX
        for _ in range(int(integrate)):
            check_cancel()
            frame = self._cam.acquire()
            used = frame.distance > 0
            if frame.confidence is not None:
                conf = frame.confidence
                used &= (conf > 0) & (conf >= threshold_code - 1e-9)
                sums.confidence += conf / k.RAW_MAX
            else:
                sums.confidence += used
            distance = frame.distance.astype(np.float64) / k.RAW_MAX * rmax
            amplitude = frame.amplitude.astype(np.float64)
            sums.phase += np.where(used, np.exp(1j * 2 * math.pi * distance / rmax), 0)
            sums.amplitude += np.where(used, amplitude, 0.0)
            sums.amplitude_all += amplitude
            sums.xyz += np.where(used[..., None], frame.xyz, 0.0)
            sums.used += used
            sums.frames += 1
            self._bump_frames(frame.integration)
        return sums

    def _bump_frames(self, integration: int) -> None:
        with self._status_lock:
            self._status["frames"] += 1
            self._status["last_frame_time"] = time.time()
            self._status["integration"] = integration
            self._status["integration_ms"] = round(k.integration_ms(integration), 2)


def _canceller(cancel: Any) -> Callable[[], None]:
    """Turn an Event, a callable (true = stop; it may also raise its own exception) or None
    into a check that raises :class:`Cancelled`."""
    if cancel is None:
        return lambda: None
    if isinstance(cancel, threading.Event):

        def check_event() -> None:
            if cancel.is_set():
                raise Cancelled("ToF grab cancelled")

        return check_event
    if callable(cancel):

        def check_callable() -> None:
            if cancel():
                raise Cancelled("ToF grab cancelled")

        return check_callable
    raise TypeError(f"cancel must be an Event, a callable or None, not {type(cancel).__name__}")
