"""The hazard cameras' front end: which pairs run, and each pair's images turned into points.

A grab exposes one pair, matches it with the stereo matcher the server gives the device (the
workflows' one: the drivers may not import it, and one matcher keeps one set of real-data
checks), and returns the matched points in the rover frame with the range noise the declared
disparity noise gives each of them. Pixels the matcher rejects (no texture, occluded, failing
its left-right check) give no point: a consumer sees only what the pair measured.
"""

from __future__ import annotations

import copy
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.base import Cancel, DeviceError, DeviceInterrupted
from drivers.stereo.errors import is_cancelled

from .backend import BACKENDS, CAMERAS, NAME, OFF_HINT, HazcamBackend, HazcamSettings
from .rig import PairRig, pair_rig

# (left, right, calibration, params) -> (N x 3 points in the left camera's optical frame, N x 2
# left pixels (row, col)) of the matched pixels; ``calibration`` holds OpenCV's K1 D1 K2 D2 R T
# image_size, ``params`` the matcher's settings by name (``min_depth``, m).
StereoMatcher = Callable[[np.ndarray, np.ndarray, Mapping[str, Any], Mapping[str, Any]], tuple[np.ndarray, np.ndarray]]


@dataclass
class HazcamFrame:
    """One pair's measurement: ``points`` (N x 3, m) in the rover frame at the instant ``stamp``
    (the backend's clock: simulated seconds for the simulator), ``sigma_range`` (N, m) the
    standard deviation of each point along its ray from ``origin`` (the left camera's centre, rover
    frame), ``pixels`` (N x 2 row, col) where each point lies in ``left``; ``left`` and ``right``
    the mono8 images it was matched from. ``capture_s`` and ``capture_cpu_s``: the wall and process
    CPU seconds the capture took on this machine (the simulator's render of both cameras, a real
    pair's exposure and transfer), apart from the matching: a consumer timing its own work on the
    frame leaves them out, as it leaves out the wait for any sensor."""

    camera: str
    stamp: float
    points: np.ndarray
    sigma_range: np.ndarray
    origin: np.ndarray
    pixels: np.ndarray
    left: np.ndarray
    right: np.ndarray
    capture_s: float = 0.0
    capture_cpu_s: float = 0.0


class Hazcam:
    """Thread-safe: grabs are serialised; status() never waits for one."""

    name = NAME

    def __init__(self, config: Mapping[str, Any] | HazcamSettings | None, backend: HazcamBackend,
                 matcher: StereoMatcher | None = None) -> None:
        """``config``: the drivers.hazcam settings; ``matcher``: see :data:`StereoMatcher` (None:
        images only, a grab of points is a DeviceError)."""
        self.config = BACKENDS.settings(config)
        self._backend = backend
        self.backend = backend.name
        self.capabilities = backend.capabilities
        self._matcher = matcher
        self._enabled: tuple[str, ...] = () if self.config.cameras == "off" else tuple(self.config.cameras.split(","))
        self._rigs: dict[str, PairRig] = {}
        self._op = threading.Lock()
        self._st = threading.Lock()
        self._status: dict[str, Any] = {"open": False, "cameras": list(self._enabled), "grabs": 0, "last_grab": None,
                                        "last_error": None}

    # -- the device protocol -------------------------------------------------------------------
    def open(self) -> None:
        """Off, there is nothing to open: the device stands, says so and refuses grabs."""
        with self._op:
            rigs = {c: pair_rig(self.config, c) for c in self._enabled}
            if self._enabled:
                self._backend.open(self._enabled)
            self._rigs = rigs
            with self._st:
                self._status["open"] = True
                self._status["last_error"] = None

    def close(self) -> None:
        with self._op:
            try:
                self._backend.close()
            finally:
                with self._st:
                    self._status["open"] = False

    def reinit(self) -> None:
        self.close()
        self.open()

    def reset(self, cancel: Cancel = None) -> None:
        """The cameras hold no state a reopen does not restore."""
        self.reinit()

    def reconfigure(self, settings: Any) -> list[str]:
        """Every key waits for the device's reinit: a pair switched on has cameras to open."""
        return []

    def status(self) -> dict[str, Any]:
        with self._st:
            out = copy.deepcopy(self._status)
        out["backend"] = self.backend
        out["enabled"] = bool(self._enabled)
        if not self._enabled:
            out["note"] = f"hazcams are off: {OFF_HINT}"
        return out

    def check(self) -> dict[str, Any]:
        with self._op:
            self._require_open()
            answers = self._backend.check(self._enabled) if self._enabled else {}
        return {**self.status(), "check": answers}

    def inject_fault(self, kind: str | None) -> None:
        raise DeviceError(NAME, f"the {self.backend} hazcams inject no faults")

    # -- the cameras ---------------------------------------------------------------------------
    def cameras(self) -> list[str]:
        """The pairs that run ("front", "rear"), in that order; empty when the hazcams are off."""
        return list(self._enabled)

    def rig(self, camera: str) -> PairRig:
        """The geometry of a running pair: its lens model and both cameras' poses on the body."""
        self._require(camera)
        return self._rigs[camera]

    def images(self, camera: str, cancel: Cancel = None) -> tuple[np.ndarray, np.ndarray]:
        """The left and right mono8 images of one pair, exposed together (no matching)."""
        with self._op:
            left, right, _, _ = self._capture(camera, cancel)
            return left, right

    def grab(self, camera: str, cancel: Cancel = None) -> HazcamFrame:
        """One pair's images matched into points (see :class:`HazcamFrame`)."""
        with self._op:
            self._require(camera)
            if self._matcher is None:
                raise DeviceError(NAME, "no stereo matcher was given to this device (the server gives its own; "
                                        "drivers.hazcam.create(..., matcher=...)): only images() works")
            left, right, stamp, captured = self._capture(camera, cancel)
            if is_cancelled(cancel):
                raise DeviceInterrupted(NAME, "grab cancelled before matching")
            rig = self._rigs[camera]
            t0 = time.perf_counter()
            try:
                pts, pixels = self._matcher(left, right, rig.calibration, {"min_depth": self.config.min_range})
            except ValueError as exc:
                raise self._failed(camera, f"stereo matching failed: {exc}") from exc
            frame = self._frame(rig, stamp, np.asarray(pts, np.float64).reshape(-1, 3),
                                np.asarray(pixels).reshape(-1, 2), left, right, captured)
            with self._st:
                self._status["last_grab"]["match_ms"] = round(1000 * (time.perf_counter() - t0), 1)
                self._status["last_grab"]["points"] = len(frame.points)
            return frame

    def _frame(self, rig: PairRig, stamp: float, pts: np.ndarray, pixels: np.ndarray, left: np.ndarray,
               right: np.ndarray, captured: tuple[float, float] = (0.0, 0.0)) -> HazcamFrame:
        """Points within max_range, to the rover frame, each with its range sigma: the depth noise
        z^2 sigma_d / (f b) of a disparity error, stretched along the ray by range / depth."""
        r = np.linalg.norm(pts, axis=1)
        z = pts[:, 2]
        keep = np.isfinite(r) & (z > 0) & (r <= self.config.max_range)
        pts, r, z = pts[keep], r[keep], z[keep]
        sigma_z = z * z * self.config.sigma_d / (rig.focal * rig.baseline)
        T = rig.T_rover_left
        return HazcamFrame(camera=rig.camera, stamp=float(stamp), points=pts @ T[:3, :3].T + T[:3, 3],
                           sigma_range=sigma_z * r / z, origin=rig.origin, pixels=pixels[keep], left=left,
                           right=right, capture_s=captured[0], capture_cpu_s=captured[1])

    def _capture(self, camera: str, cancel: Cancel) -> tuple[np.ndarray, np.ndarray, float, tuple[float, float]]:
        """The pair's images, their stamp, and the wall and process CPU seconds the capture took."""
        self._require(camera)
        self._require_open()
        t0, cpu0 = time.perf_counter(), time.process_time()
        try:
            left, right, stamp = self._backend.capture(self._rigs[camera], cancel)
        except DeviceInterrupted:
            raise
        except DeviceError as exc:
            raise self._failed(camera, exc.message) from exc
        captured = (time.perf_counter() - t0, time.process_time() - cpu0)
        with self._st:
            self._status["grabs"] += 1
            self._status["last_error"] = None
            self._status["last_grab"] = {"camera": camera, "stamp": stamp, "capture_ms": round(1000 * captured[0], 1)}
        return left, right, stamp, captured

    def _require(self, camera: str) -> None:
        if camera not in CAMERAS:
            raise ValueError(f"no hazcam {camera!r}; the body's pairs are {', '.join(CAMERAS)}")
        if not self._enabled:
            raise DeviceError(NAME, f"hazcams are off: {OFF_HINT}")
        if camera not in self._enabled:
            raise DeviceError(NAME, f"the {camera} hazcams are off (drivers.hazcam.cameras is "
                                    f"{self.config.cameras}): {OFF_HINT}")

    def _require_open(self) -> None:
        if not self._status["open"]:
            raise DeviceError(NAME, "hazcams are not open (reinit -device hazcam)")

    def _failed(self, camera: str, message: str) -> DeviceError:
        with self._st:
            self._status["last_error"] = f"{camera}: {message}"
        return DeviceError(NAME, f"{camera} pair: {message}")
