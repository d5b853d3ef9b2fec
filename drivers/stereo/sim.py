"""Simulated PIKE F-210B pair: renders the shared world from the left and right mounts.

In external trigger mode a simulated camera captures only when the world's trigger bus pulses
(fired by the simulated trigger box); both cameras take their poses from one snapshot read at
the pulse, so a pair always shows one instant even while the rover or the PTU moves. Rendering
a frame is where a simulated grab spends its time (seconds at the highest resolution): a grab's
``cancel`` is passed into the render and looked at between its stages, as a real camera's is
between polls for the frame.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.registry import Capability
from drivers.sim.render import RenderCancelled
from drivers.stereo import imaging
from drivers.stereo.backend import BACKENDS
from drivers.stereo.errors import CameraLost, GrabCancelled, MissedTrigger, is_cancelled
from drivers.stereo.modes import channels
from drivers.stereo.settings import CameraSettings
from rvs_params import Settings, param

# GUID-like ids with AVT's IEEE OUI (00:0a:47); the first is mounted left, the second right.
SIM_GUIDS = ("000a470112f20001", "000a470112f20002")
MOUNTS = ("left", "right")
FAULTS = ("no_trigger", "unplug")
DEFAULT_DISTORTION = (-0.06, 0.012, 0.0, 0.0, 0.0)  # mild barrel of a ~60 deg lens


_S, _L = imaging.SensorModel(), imaging.Lighting()  # defaults of the keys below


@dataclass
class SimStereoSettings(Settings):
    """drivers.stereo keys of the simulated pair: its lenses, its sensor noise and the light."""

    seed: int = param(0, "sim: sensor noise seed", min=0, max=2**63 - 1)
    sim_guids: list = param(list(SIM_GUIDS), "sim: the two camera ids (left mount, right mount)")
    sim_distortion: list[float] = param(list(DEFAULT_DISTORTION), "sim: OpenCV k1 k2 p1 p2 [k3 ...] of both lenses",
                                        length=(4, 8))
    sim_hfov_deg: float | None = param(None, "sim: horizontal field of view; null = the world's camera model",
                                       unit="deg", min=1.0, max=179.0)
    sim_noise: bool = param(_S.noise, "sim: shot + read noise")
    sim_full_well_e: float = param(_S.full_well_e, "sim: full well", unit="e-", min=1.0)
    sim_read_noise_e: float = param(_S.read_noise_e, "sim: read noise", unit="e-", min=0.0)
    sim_white_dn: float = param(_S.white_dn_at_ref, "sim: grey level of a white lit surface at 8 ms, 0 dB",
                                unit="DN", min=0.0)
    sim_sun_azimuth_deg: float | None = param(None, "sim: direction the light comes from (global frame, CCW "
                                              "from +x); null = the scene's sun block (200 unless it says)",
                                              unit="deg", min=-360.0, max=360.0)
    sim_sun_elevation_deg: float | None = param(None, "sim: sun elevation; null = the scene's sun block (45 "
                                                "unless it says)", unit="deg", min=-90.0, max=90.0)
    sim_ambient: float = param(_L.ambient, "sim: share of light independent of surface orientation", min=0.0,
                               max=1.0)
    sim_sky: float = param(_L.sky, "sim: radiance of pixels that hit nothing, relative to a white lit surface",
                           min=0.0)
    sim_scene: str = param("office", "sim: the scene of a pair used with no shared world (consoles, scripts)")
    sim_parallel: bool = param(True, "sim: render the two cameras in two threads")


@BACKENDS.backend("sim")
class SimCameras:
    settings = SimStereoSettings
    capabilities = frozenset({Capability.FAULTS, Capability.TRUTH})
    faults = FAULTS

    def __init__(self, config: Any, world: Any = None) -> None:
        """``config``: the composed drivers.stereo settings (StereoSettings and SimStereoSettings keys)."""
        self.world = world
        guids = [str(g).lower() for g in config.sim_guids]
        if len(guids) != 2:
            raise ValueError("sim_guids must list two camera ids (left mount, right mount)")
        self._mount = dict(zip(guids, MOUNTS, strict=True))
        self._guids = guids
        self.distortion = np.asarray(config.sim_distortion, dtype=np.float64)
        if self.distortion.size not in (4, 5, 8):
            raise ValueError("sim_distortion must hold 4, 5 or 8 OpenCV coefficients (k1 k2 p1 p2 [k3 ...])")
        self.sensor = imaging.sensor_from_config(config)
        self._config = config  # the light is read per frame: it follows the scene's sun
        self.hfov_deg = config.sim_hfov_deg
        self.seed = config.seed
        self.scene = config.sim_scene
        self.parallel = config.sim_parallel
        self._lock = threading.Lock()  # faults, lost set, settings
        self._faults: dict[str, str | None] = dict.fromkeys(guids)
        self._lost: set[str] = set()
        self._settings: dict[str, CameraSettings] = {}
        self._rngs: dict[str, np.random.Generator] = {}
        self._effective_shutter: dict[str, float] = {}
        self._pool: ThreadPoolExecutor | None = None
        self._open = False

    # -- bus ---------------------------------------------------------------------------------
    def open(self) -> list[str]:
        if self.world is None:
            from drivers.sim.world import World  # the default world only when nobody shared one

            self.world = World.from_scene(self.scene, seed=self.seed)
        with self._lock:
            self._lost = {g for g in self._guids if self._faults[g] == "unplug"}
            self._rngs = {g: np.random.default_rng([self.seed, i]) for i, g in enumerate(self._guids)}
        if self._pool is None and self.parallel:
            self._pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="sim-cam")
        self._open = True
        return self.available()

    def available(self) -> list[str]:
        with self._lock:
            return [g for g in self._guids if self._faults[g] != "unplug"]

    def close(self) -> None:
        self._open = False
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None

    def describe(self, guid: str) -> dict[str, Any]:
        return {"vendor": "AVT (simulated)", "model": "PIKE F-210B", "mount": self._mount.get(guid)}

    # -- faults ------------------------------------------------------------------------------
    def inject_fault(self, kind: str | None, guids: list[str] | None = None) -> None:
        if kind is not None and kind not in FAULTS:
            raise ValueError(f"unknown stereo fault {kind!r}; accepted: {', '.join(FAULTS)} or None")
        with self._lock:
            for guid in guids or self._guids:
                self._faults[guid] = kind

    def active_faults(self) -> dict[str, str | None]:
        with self._lock:
            return dict(self._faults)

    def _require(self, guid: str) -> None:
        with self._lock:
            if guid not in self._mount:
                raise CameraLost(guid, "(no such camera on the simulated bus)")
            if self._faults[guid] == "unplug":
                self._lost.add(guid)
            if guid in self._lost:
                raise CameraLost(guid)

    # -- settings ----------------------------------------------------------------------------
    def apply_settings(self, guid: str, settings: CameraSettings) -> None:
        self._require(guid)
        with self._lock:
            self._settings[guid] = settings

    def hardware_reset(self, guids: list[str]) -> None:
        for guid in guids:
            with self._lock:
                if self._faults[guid] == "unplug":
                    raise CameraLost(guid)
                self._lost.discard(guid)
                self._settings.pop(guid, None)

    def check(self, guids: list[str]) -> dict[str, Any]:
        for guid in guids:
            self._require(guid)
        return {g: {"responding": True, "shutter_us": self._settings_of(g).shutter_us} for g in guids}

    def _settings_of(self, guid: str) -> CameraSettings:
        with self._lock:
            return self._settings.get(guid, CameraSettings())

    # -- capture -----------------------------------------------------------------------------
    def arm(self, guids: list[str], size: tuple[int, int], pixel_format: str) -> dict[str, Any]:
        for guid in guids:
            self._require(guid)
        return {"guids": list(guids), "size": size, "format": pixel_format, "after": self.world.trigger.count}

    def disarm(self, token: dict[str, Any]) -> None:
        pass

    def collect(self, token: dict[str, Any], timeout: float, cancel: Any = None) -> dict[str, np.ndarray]:
        guids: list[str] = token["guids"]
        after: int = token["after"]
        bus = self.world.trigger
        deadline = time.monotonic() + timeout
        pulse = None
        deaf = [g for g in guids if self.active_faults()[g] == "no_trigger"]
        while pulse is None and len(deaf) < len(guids):
            if is_cancelled(cancel):
                raise GrabCancelled("grab cancelled while waiting for the trigger")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise MissedTrigger(guids, timeout, after)
            pulse = bus.wait_for_pulse(after, min(0.05, remaining))
        if pulse is not None:
            poses = self._snapshot([self._mount[g] for g in guids])  # the instant of the pulse
        if deaf:  # a camera that never sees the pulse waits out its timeout like the real one
            while (remaining := deadline - time.monotonic()) > 0:
                if is_cancelled(cancel):
                    raise GrabCancelled("grab cancelled while waiting for the trigger")
                time.sleep(min(0.05, remaining))
            raise MissedTrigger(deaf, timeout, after)
        for guid in guids:  # unplugged between arming and the pulse
            self._require(guid)
        return self._render_all(guids, poses, token["size"], token["format"], cancel)

    def capture_direct(
        self, guids: list[str], size: tuple[int, int], pixel_format: str, timeout: float, cancel: Any = None
    ) -> dict[str, np.ndarray]:
        for guid in guids:
            self._require(guid)
        if is_cancelled(cancel):
            raise GrabCancelled("grab cancelled")
        poses = self._snapshot([self._mount[g] for g in guids])
        return self._render_all(guids, poses, size, pixel_format, cancel)

    def last_shutter(self) -> dict[str, float]:
        with self._lock:
            return dict(self._effective_shutter)

    def _snapshot(self, mounts: list[str]) -> dict[str, np.ndarray]:
        """Poses of all mounts at one instant: re-read until nothing moved while reading."""
        poses: dict[str, np.ndarray] = {}
        for _ in range(10):
            poses = {m: np.array(self.world.sensor_pose(m), dtype=np.float64) for m in mounts}
            again = np.asarray(self.world.sensor_pose(mounts[0]), dtype=np.float64)
            if np.array_equal(again, poses[mounts[0]]):
                break
        return poses

    def intrinsics(self, mount: str, size: tuple[int, int]) -> np.ndarray:
        w, h = size
        if self.hfov_deg is not None:
            f = (w / 2.0) / np.tan(np.radians(float(self.hfov_deg)) / 2.0)
            return np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
        return np.asarray(self.world.camera_intrinsics(mount, w, h), dtype=np.float64)

    def _render_all(
        self, guids: list[str], poses: dict[str, np.ndarray], size: tuple[int, int], pixel_format: str,
        cancel: Any = None,
    ) -> dict[str, np.ndarray]:
        jobs = [(g, poses[self._mount[g]]) for g in guids]
        if self._pool is not None and len(jobs) > 1:
            futures = [self._pool.submit(self._render_one, g, pose, size, pixel_format, cancel) for g, pose in jobs]
            return {g: f.result() for (g, _), f in zip(jobs, futures, strict=True)}
        return {g: self._render_one(g, pose, size, pixel_format, cancel) for g, pose in jobs}

    def _render_one(self, guid: str, pose: np.ndarray, size: tuple[int, int], pixel_format: str,
                    cancel: Any = None) -> np.ndarray:
        def stop() -> bool:
            return is_cancelled(cancel)

        def check() -> None:
            if stop():
                raise GrabCancelled("grab cancelled while the frame was read out")

        settings = self._settings_of(guid)
        K = self.intrinsics(self._mount[guid], size)
        dmap = imaging.distortion_map(K, self.distortion, size, check)
        w, h = dmap.render_size
        try:  # (no cancel, no keyword: a stand-in world of the tests need not take one)
            r = (self.world.render(dmap.K_render, w, h, pose) if cancel is None
                 else self.world.render(dmap.K_render, w, h, pose, cancel=stop))
        except RenderCancelled:
            raise GrabCancelled("grab cancelled while the frame was read out") from None
        check()
        hit = np.isfinite(r.depth)
        optics = self.world.optics
        rad = imaging.radiance(r.albedo, r.normal, hit, imaging.lighting_from_config(self._config, self.world.sun),
                               r.sunlit)
        check()  # each stage takes a tenth of a second or more at the highest resolution
        if channels(pixel_format) == 3:
            rad = rad[..., None] * imaging.white_balance_gains(settings.white_balance)
        rad = imaging.lens_blur(rad, optics.blur_sigma_px)
        check()
        rad = imaging.apply_distortion(rad, dmap)
        rad = imaging.vignette(rad, K, optics.vignetting)
        check()
        shutter = float(settings.shutter_us)
        if settings.auto_exposure:
            shutter = imaging.auto_shutter(rad, settings.target_grey, settings.gain_db, self.sensor)
        with self._lock:
            self._effective_shutter[guid] = shutter
            rng = self._rngs.get(guid)
        exposed = imaging.expose(rad, shutter, settings.gain_db, self.sensor, rng)
        check()
        return imaging.jpeg(exposed, optics.jpeg_quality)

    def calibration(self, left: str, right: str, size: tuple[int, int]) -> dict[str, Any]:
        """Ground truth: the world's intrinsics, the configured distortion, the mounts' relative pose."""
        poses = self._snapshot([self._mount[left], self._mount[right]])
        T_w_l, T_w_r = poses[self._mount[left]], poses[self._mount[right]]
        T_r_l = np.linalg.inv(T_w_r) @ T_w_l  # x_right = R x_left + T (cv2.stereoCalibrate convention)
        return {
            "K1": self.intrinsics(self._mount[left], size),
            "D1": self.distortion.copy(),
            "K2": self.intrinsics(self._mount[right], size),
            "D2": self.distortion.copy(),
            "R": T_r_l[:3, :3].copy(),
            "T": T_r_l[:3, 3].copy(),
            "image_size": [int(size[0]), int(size[1])],
            "source": "simulated world (ground truth)",
        }
