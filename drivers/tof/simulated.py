"""Simulated SR4000: renders the shared world from the ToF's pose and measures it like the camera.

It answers the same register-level calls as the libMesaSR backend and returns the same raw
16-bit images, so the device layer above cannot tell them apart. The signal and error model is
in :mod:`drivers.tof.physics`; this module does the rendering, the per-frame noise, the on-chip
filters (median, adaptive neighbourhood), the auto-exposure loop and injected faults.

Faults (``inject_fault``), chosen so a server test can script them:

* ``"unplug"``: the USB link is gone. Every call raises ``DeviceError("tof", "SR4000
  disconnected (USB) ...")`` and the handle is lost. It persists until ``inject_fault(None)``
  (the cable is back); the camera then stays closed until ``reinit()``/``reset()`` reopens it.
* ``"timeout"``: the camera stays enumerated but no frame arrives: every acquire raises a
  timeout DeviceError until ``inject_fault(None)``; settings calls still work.
* ``after=n`` delays the fault by n successful acquisitions ("unplugged mid-stream").

AM_SHORT_RANGE (enhanced XYZ) is accepted and reported, but the simulated optics have no
short-range coordinate error for it to correct, so it changes nothing in the images. Renders
are cached per camera pose, modulation, integration time and world state, so the N frames of
one integration cost one render; every frame draws fresh noise from the seeded generator.
"""

from __future__ import annotations

import math
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from drivers.base import DeviceError
from drivers.registry import Capability
from rvs_params import Settings, param

from . import constants as k
from .backend import BACKENDS, DeviceInfo, RawFrame, SR4000Settings
from .physics import SignalModel, block_mean, direct_phasor, multipath_phasor, phasor_range, pixel_solid_angle

FAULTS = ("unplug", "timeout")
# Views rendered ahead with no frame taken since: one two-axis move (the PTU names its pan, then
# its tilt). A frame taken renders where it is if nothing was rendered there ahead.
AHEAD_UNUSED = 2
DEFAULT_SIM_SERIAL = 0x4000002F
_M = SignalModel()


@dataclass
class SimTofSettings(Settings):
    """drivers.tof keys of the simulated camera. Noise model (drivers/tof/physics.py): range sigma =
    sqrt(floor^2 + (k * (30 MHz / f) / amplitude)^2), amplitude = gain * albedo * cos(incidence) /
    range^2 * integration_ms: 1 cm on the office floor 1.5 m away."""

    seed: int = param(0, "sim: noise generator seed", min=0, max=2**63 - 1)
    sim_serial: int = param(DEFAULT_SIM_SERIAL, "sim: the serial number the simulated camera reports",
                            min=0, max=0xFFFFFFFF)
    time_scale: float | None = param(None, "sim: wall seconds per simulated second of a frame (4 x integration "
                                     "+ 5 ms; 1 real time, 0 instant); null: frames take their time on the "
                                     "simulated world's clock (sim.time_scale)", min=0.0, max=1000.0)
    scene: str = param("office", "sim: the scene of a camera used with no shared world (consoles, scripts)")
    sim_amplitude_gain: float = param(_M.amplitude_gain, "sim: counts per (albedo * cos / m^2 * ms)", min=1e-9)
    sim_saturation: float = param(_M.saturation, "sim: brighter pixels saturate (confidence 0, range unusable)",
                                  unit="counts", min=1e-9)
    sim_noise_k: float = param(_M.noise_k, "sim: range noise at 30 MHz", unit="m*counts", min=0.0)
    sim_noise_floor: float = param(_M.noise_floor, "sim: range sigma never falls below this", unit="m", min=0.0)
    sim_amplitude_noise: float = param(_M.amplitude_noise, "sim: amplitude sigma = this * sqrt(amplitude)",
                                       min=0.0)
    sim_confidence_amplitude: float = param(_M.confidence_amplitude, "sim: confidence = 1 - exp(-amplitude / this)",
                                            unit="counts", min=1e-9)
    sim_fixed_pattern_sigma: float = param(_M.fixed_pattern_sigma, "sim: per-pixel offsets left when fix_pattern "
                                           "correction is off", unit="m", min=0.0)
    sim_multipath_gain: float = param(_M.multipath_gain, "sim: wall-floor inter-reflection (ranges too long "
                                      "near walls); 0 = off", min=0.0)
    sim_multipath_block: int = param(_M.multipath_block, "sim: native pixels per side of one inter-reflection "
                                     "source patch", min=1, max=176)
    sim_multipath_step: int = param(_M.multipath_step, "sim: multipath on every n-th pixel, interpolated between",
                                    min=1, max=176)
    sim_supersample: int = param(_M.supersample, "sim: sub-pixels per side: mixed (flying) pixels at depth "
                                 "edges; 1 = off", min=1, max=16)
    sim_conv_gray_reference_m: float = param(_M.conv_gray_reference_m, "sim: AM_CONV_GRAY scales amplitude by "
                                             "(range / this)^2", unit="m", min=1e-6)


@dataclass
class _Expected:
    """The noise-free measurement for one pose and setting: what every frame scatters around."""

    range: np.ndarray  # m, wrapped into [0, c/2f)
    amplitude: np.ndarray  # counts, before saturation clipping
    hit: np.ndarray  # bool: some light returned
    saturated: np.ndarray  # bool
    rays: np.ndarray  # (H, W, 3) unit directions, OpenCV camera frame


def nominal_camera_matrix(width: int = k.WIDTH, height: int = k.HEIGHT) -> np.ndarray:
    """Pinhole matrix from the SR4000's 43.6 x 34.6 degree field of view."""
    fx = (width / 2.0) / math.tan(math.radians(k.FOV_H_DEG) / 2.0)
    fy = (height / 2.0) / math.tan(math.radians(k.FOV_V_DEG) / 2.0)
    return np.array([[fx, 0.0, (width - 1) / 2.0], [0.0, fy, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def config_intrinsics(config: SR4000Settings) -> tuple[np.ndarray | None, np.ndarray]:
    K = config.camera_matrix
    if K is not None:
        K = np.asarray(K, dtype=np.float64).reshape(3, 3)
    dist = np.zeros(5)
    if config.distortion is not None:
        d = np.asarray(config.distortion, dtype=np.float64).reshape(-1)
        dist[: min(5, d.size)] = d[:5]
    return K, dist


def world_state(world: Any) -> Any:
    """What, besides the camera pose, makes two renders differ: the scene and moving things.

    A world may offer a ``revision`` counter; otherwise the scene identity, the target's pose
    and the objects (and checkerboard corners) present stand in for it.
    """
    revision = getattr(world, "revision", None)
    if revision is not None:
        return revision
    parts: list[Any] = [id(getattr(world, "terrain", None))]
    target_pose = getattr(world, "target_pose", None)
    parts.append(target_pose() if callable(target_pose) else None)
    ids = getattr(world, "object_ids", None)
    if isinstance(ids, dict):
        parts.append(tuple(sorted(ids.items())))
        if "checkerboard" in ids and hasattr(world, "checkerboard_corners"):
            parts.append(np.asarray(world.checkerboard_corners()).tobytes())
    return tuple(parts)


@BACKENDS.backend("sim")
class SimTof:
    """The simulated camera (register level)."""

    settings = SimTofSettings
    capabilities = frozenset({Capability.FAULTS, Capability.LINK_CHECK})
    faults = FAULTS
    rows = k.HEIGHT
    cols = k.WIDTH

    def __init__(self, config: Any, world: Any = None) -> None:
        """``config``: the composed drivers.tof settings (SR4000Settings and SimTofSettings keys)."""
        if world is None:
            world = _default_world(config)
        self._world = world
        self.model = SignalModel.from_config(config)
        seed = config.seed
        self._rng = np.random.default_rng(seed)
        self._fixed_pattern = np.random.default_rng([seed, 1]).normal(0.0, self.model.fixed_pattern_sigma, (self.rows, self.cols))
        self._serial = config.sim_serial
        self._timeout = config.timeout
        self._time_scale = config.time_scale
        K, self._dist = config_intrinsics(config)
        self._K = K if K is not None else np.asarray(world.camera_intrinsics("tof", self.cols, self.rows), dtype=np.float64)
        self._lock = threading.Lock()  # guards fault state, which tests flip from other threads
        self._fault: str | None = None
        self._pending: tuple[str, int] | None = None
        self._open = False
        self._integration = 30
        self._frequency = 30.0
        self._threshold = 0
        self._mode = int(k.AcquireMode.AM_SW_TRIGGER)
        self._ae: tuple[int, int, int, int] | None = None
        self._cache_key: tuple | None = None
        self._cache: _Expected | None = None
        # the view where the PTU is heading, rendered while it travels (one at a time, the latest)
        self._ahead: tuple[tuple, Future[_Expected]] | None = None
        self._ahead_pool: ThreadPoolExecutor | None = None  # while open
        # renders ahead since the last frame: a camera that takes none while the PTU moves (a
        # stereo scan, orient) stops rendering views it never uses after AHEAD_UNUSED of them
        self._ahead_unused = 0
        self._view: tuple[tuple, Any] | None = None  # the last render of the scene: (T and world state, Render)
        self.frames = 0
        self._rays, self._undist_maps = self._ray_geometry()

    # -- faults ----------------------------------------------------------------------------
    def inject_fault(self, kind: str | None, after: int = 0) -> None:
        """Start ("unplug", "timeout") or clear (None) a fault; ``after`` frames from now."""
        if kind is not None and kind not in FAULTS:
            raise ValueError(f"unknown ToF fault {kind!r}; known: {', '.join(FAULTS)} or None")
        with self._lock:
            if kind is None:
                self._fault, self._pending = None, None
            elif after > 0:
                self._pending = (kind, int(after))
            else:
                self._activate(kind)

    @property
    def fault(self) -> str | None:
        with self._lock:
            return self._fault

    def _activate(self, kind: str) -> None:
        self._fault, self._pending = kind, None
        if kind == "unplug":
            self._open = False

    def check_link(self) -> None:
        """Raise the disconnect error while unplugged (before any generic "not open")."""
        with self._lock:
            fault = self._fault
        if fault == "unplug":
            self._open = False
            raise DeviceError(
                "tof",
                f"SR4000 disconnected (USB): camera 0x{self._serial:08X} does not answer; "
                "reconnect the USB cable and power, then reinit or reset",
            )

    def _check_open(self) -> None:
        self.check_link()
        if not self._open:
            raise DeviceError("tof", "SR4000 not open (the handle was lost or closed); run reinit or reset")

    # -- identification --------------------------------------------------------------------
    def open(self, serial: int) -> None:
        with self._lock:
            unplugged = self._fault == "unplug"
        if unplugged:
            raise DeviceError("tof", "no SR4000 found on the USB bus (SR_OpenUSB found none); check the USB cable and power")
        if serial not in (0, self._serial):
            raise DeviceError(
                "tof", f"no SR4000 with serial 0x{serial:08X} on the USB bus (found 0x{self._serial:08X}); use 0 for the first camera"
            )
        self._open = True
        self._ahead_unused = 0
        if self._ahead_pool is None and hasattr(self._world, "watch_ptu_target"):
            self._ahead_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="tof-ahead")
            self._world.watch_ptu_target(self._render_ahead)

    def close(self) -> None:
        self._open = False
        if self._ahead_pool is not None:
            self._world.unwatch_ptu_target(self._render_ahead)
            self._ahead_pool.shutdown(wait=False, cancel_futures=True)
            self._ahead_pool, self._ahead = None, None

    @property
    def is_open(self) -> bool:
        return self._open

    def info(self) -> DeviceInfo:
        self._check_open()
        vid, pid = k.SR4000_VENDOR_ID, k.SR4000_PRODUCT_IDS[0]
        manufacturer, product = "MESA Imaging", "SR4000 (simulated)"
        text = f"VendorID:0x{vid:04x}, ProductID:0x{pid:04x}, Manufacturer:'{manufacturer}', Product:'{product}'"
        return DeviceInfo(self._serial, vid, pid, manufacturer, product, text)

    def intrinsics(self) -> tuple[np.ndarray, np.ndarray]:
        return self._K.copy(), self._dist.copy()

    # -- registers -------------------------------------------------------------------------
    def set_integration(self, register: int) -> None:
        self._check_open()
        self._integration = k.check_integration(register)

    def get_integration(self) -> int:
        self._check_open()
        return self._integration

    def set_modulation(self, frequency_mhz: float) -> None:
        self._check_open()
        self._frequency = k.check_frequency(frequency_mhz)

    def get_modulation(self) -> float:
        self._check_open()
        return self._frequency

    def set_amplitude_threshold(self, value: int) -> None:
        self._check_open()
        if not 0 <= int(value) <= k.RAW_MAX:
            raise ValueError(f"amplitude threshold {value} outside 0..65535")
        self._threshold = int(value)

    def set_mode(self, mode: int) -> None:
        self._check_open()
        self._mode = int(mode)

    def get_mode(self) -> int:
        self._check_open()
        return self._mode

    def set_auto_exposure(self, min_integration: int, max_integration: int, percent_over: int, desired: int) -> None:
        self._check_open()
        if int(min_integration) == 0xFF:
            self._ae = None
        else:
            self._ae = (int(min_integration), int(max_integration), int(percent_over), int(desired))

    # -- acquisition -----------------------------------------------------------------------
    def acquire(self) -> RawFrame:
        self._check_open()
        with self._lock:
            if self._pending is not None:
                kind, left = self._pending
                if left <= 0:
                    self._activate(kind)
                else:
                    self._pending = (kind, left - 1)
            fault = self._fault
        self.check_link()
        if fault == "timeout":
            raise DeviceError(
                "tof",
                f"SR_Acquire timed out after {self._timeout:.1f} s: camera 0x{self._serial:08X} sent no frame; "
                "check the USB link, then reinit",
            )
        integration = self._integration
        t_ms = k.integration_ms(integration)
        frame_s = k.frame_seconds(t_ms)
        if self._time_scale is None:
            if not self._world.rolling:  # exposed while the rover rolls, the frame overlaps the drive
                self._world.clock.sleep(frame_s, what="tof frames")
        elif self._time_scale > 0:
            time.sleep(self._time_scale * frame_s)
        self._ahead_unused = 0
        frame = self._measure(self._expected(t_ms), integration)
        self.frames += 1
        return frame

    def _key(self, T: np.ndarray, t_ms: float) -> tuple:
        return (T.tobytes(), self._frequency, t_ms, world_state(self._world))

    def _expected(self, t_ms: float) -> _Expected:
        T = np.asarray(self._world.sensor_pose("tof"), dtype=np.float64)
        key = self._key(T, t_ms)
        if key != self._cache_key or self._cache is None:
            ahead = self._ahead
            if ahead is not None and ahead[0] == key:
                self._cache = ahead[1].result()
            else:
                self._cache = self._render_expected(T, t_ms)
            self._cache_key = key
        return self._cache

    def _render_ahead(self, pan: float, tilt: float) -> None:
        """The PTU started toward (pan, tilt): render the view there while it travels, so that a
        grab on arrival costs what the camera's frame costs, not the simulator's render too."""
        pool = self._ahead_pool
        if not self._open or pool is None or self._ahead_unused >= AHEAD_UNUSED:
            return
        T = np.asarray(self._world.sensor_pose_at("tof", pan, tilt), dtype=np.float64)
        t_ms = k.integration_ms(self._integration)
        key = self._key(T, t_ms)
        ahead = self._ahead
        if ahead is not None and ahead[0] == key:
            return
        if ahead is not None:
            ahead[1].cancel()  # superseded before it started: a two-axis move names its pan first
        try:
            self._ahead = (key, pool.submit(self._render_expected, T, t_ms))
            self._ahead_unused += 1
        except RuntimeError:  # closed meanwhile: the grab renders for itself, as without this
            self._ahead = None

    def _ray_geometry(self) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, int] | None]:
        """Unit ray per raw pixel, and (when distorted) where each raw pixel lies in the pinhole image."""
        u, v = np.meshgrid(np.arange(self.cols, dtype=np.float64), np.arange(self.rows, dtype=np.float64))
        if np.any(self._dist):
            pts = np.stack([u.ravel(), v.ravel()], axis=-1).reshape(-1, 1, 2)
            norm = cv2.undistortPoints(pts, self._K, self._dist).reshape(self.rows, self.cols, 2)
            x, y = norm[..., 0], norm[..., 1]
            pu = self._K[0, 0] * x + self._K[0, 2]
            pv = self._K[1, 1] * y + self._K[1, 2]
            margin = int(math.ceil(max(-pu.min(), -pv.min(), pu.max() - (self.cols - 1), pv.max() - (self.rows - 1), 0.0))) + 2
            maps = ((pu + margin).astype(np.float32), (pv + margin).astype(np.float32), margin)
        else:
            x = (u - self._K[0, 2]) / self._K[0, 0]
            y = (v - self._K[1, 2]) / self._K[1, 1]
            maps = None
        rays = np.stack([x, y, np.ones_like(x)], axis=-1)
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
        return rays.astype(np.float64), maps

    def _render_expected(self, T: np.ndarray, t_ms: float) -> _Expected:
        m = self._undist_maps[2] if self._undist_maps is not None else 0
        w, h = self.cols + 2 * m, self.rows + 2 * m
        K = self._K.copy()
        K[0, 2] += m
        K[1, 2] += m
        s = self.model.supersample
        Ks = K.copy()
        Ks[0, 0] *= s
        Ks[1, 1] *= s
        Ks[0, 2] = s * K[0, 2] + (s - 1) / 2.0
        Ks[1, 2] = s * K[1, 2] + (s - 1) / 2.0
        # the scene's geometry seen from T does not depend on the modulation: the wrap check's
        # second frequency reuses the render (the render is three quarters of the cost)
        view_key = (T.tobytes(), world_state(self._world))
        seen = self._view
        if seen is not None and seen[0] == view_key:
            r = seen[1]
        else:
            r = self._world.render(Ks, w * s, h * s, T)
            self._view = (view_key, r)
        f = self._frequency
        amp_s = self.model.amplitude(np.asarray(r.albedo), np.asarray(r.cos_incidence), np.asarray(r.range), t_ms)
        phasor = block_mean(direct_phasor(amp_s, np.asarray(r.range, dtype=np.float64), f), s)
        if self.model.multipath_gain > 0:
            c = s // 2
            pts = np.asarray(r.points)[c::s, c::s]
            nrm = np.asarray(r.normal)[c::s, c::s]
            alb = np.asarray(r.albedo, dtype=np.float64)[c::s, c::s]
            mp = multipath_phasor(
                pts, nrm, alb, T[:3, 3], pixel_solid_angle(K, w, h), f, self.model.multipath_block,
                target_step=self.model.multipath_step,
            )
            phasor = phasor + self.model.multipath_gain * self.model.amplitude_gain * t_ms * mp
        if self._undist_maps is not None:
            mx, my, _ = self._undist_maps
            re = cv2.remap(phasor.real.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            im = cv2.remap(phasor.imag.astype(np.float32), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
            phasor = re.astype(np.float64) + 1j * im.astype(np.float64)
        amplitude = np.abs(phasor)
        hit = amplitude > 1e-6
        return _Expected(
            range=phasor_range(phasor, f),
            amplitude=amplitude,
            hit=hit,
            saturated=amplitude > self.model.saturation,
            rays=self._rays,
        )

    def _measure(self, e: _Expected, integration: int) -> RawFrame:
        """One noisy frame around the expectation, through the on-chip corrections."""
        model, rng, f = self.model, self._rng, self._frequency
        rmax = k.unambiguous_range(f)
        mode = self._mode
        shape = e.range.shape
        sigma = model.range_sigma(e.amplitude, f)
        rng_m = e.range + rng.standard_normal(shape) * sigma
        if not mode & k.AcquireMode.AM_COR_FIX_PTRN:
            rng_m = rng_m + self._fixed_pattern
        amp = e.amplitude + model.amplitude_noise * np.sqrt(e.amplitude) * rng.standard_normal(shape)
        # No return: the pixel sees only read-out noise and reports an arbitrary phase.
        amp = np.where(e.hit, amp, np.abs(rng.standard_normal(shape)) * 3.0)
        rng_m = np.where(e.hit, rng_m, rng.uniform(0.0, rmax, shape))
        amp = np.clip(amp, 0.0, model.saturation)
        rng_m = np.where(e.saturated, rng.uniform(0.0, rmax, shape), rng_m)
        rng_m = np.mod(rng_m, rmax)
        if mode & (k.AcquireMode.AM_MEDIAN | k.AcquireMode.AM_MEDIANCROSS):
            rng_m = cv2.medianBlur(rng_m.astype(np.float32), 3).astype(np.float64)
        if mode & k.AcquireMode.AM_DENOISE_ANF:
            typical = float(np.median(sigma[e.hit])) if e.hit.any() else 0.01
            rng_m = cv2.bilateralFilter(rng_m.astype(np.float32), 5, 3.0 * typical, 1.5).astype(np.float64)
        confidence = model.confidence(amp, e.saturated) * e.hit
        codes = np.clip(np.rint(rng_m / rmax * k.RAW_MAX), 1, k.RAW_MAX).astype(np.uint16)
        codes[amp < self._threshold] = 0
        measured = codes.astype(np.float64) / k.RAW_MAX * rmax
        xyz = (measured[..., None] * e.rays).astype(np.float32)
        xyz[codes == 0] = 0.0
        amp_out = amp
        if mode & k.AcquireMode.AM_CONV_GRAY:
            amp_out = amp * np.square(measured / model.conv_gray_reference_m)
        self._auto_expose(amp, e.hit)
        return RawFrame(
            distance=codes,
            amplitude=np.clip(np.rint(amp_out), 0, k.RAW_MAX).astype(np.uint16),
            confidence=np.rint(confidence * k.RAW_MAX).astype(np.uint16) if mode & k.AcquireMode.AM_CONF_MAP else None,
            xyz=xyz,
            integration=integration,
        )

    def _auto_expose(self, amplitude: np.ndarray, hit: np.ndarray) -> None:
        """libMesaSR's auto exposure: move the histogram point with ``percent_over`` percent of the
        pixels above it toward ``desired`` (8-bit scale), a bit per frame."""
        if self._ae is None or not hit.any():
            return
        lo, hi, percent_over, desired = self._ae
        amp8 = np.clip(amplitude[hit] / self.model.saturation * 255.0, 0.0, 255.0)
        position = max(float(np.percentile(amp8, 100.0 - percent_over)), 0.5)
        t_ms = k.integration_ms(self._integration)
        t_new = t_ms * (1.0 + 0.5 * (desired / position - 1.0))
        t_new = min(max(t_new, k.INTEGRATION_BASE_MS), k.INTEGRATION_BASE_MS + k.INTEGRATION_STEP_MS * 255)
        self._integration = int(min(max(k.integration_register(t_new), lo), hi))


def _default_world(config: Any) -> Any:
    """A world of its own for a simulated camera used outside the server (consoles, scripts)."""
    try:
        from drivers.sim.world import World
    except ImportError as exc:
        raise DeviceError("tof", f"simulated backend needs drivers.sim ({exc})") from None
    return World.from_scene(config.scene, seed=config.seed)
