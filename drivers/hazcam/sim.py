"""Simulated hazard camera pairs: both cameras of a pair rendered from the shared world at one
instant of the rover's pose, imaged as the simulated PIKE cameras are (the scene's sun and
shadows, its optics, one auto exposure for the pair, shot and read noise), so what the front
end matches is an image, never the renderer's depth.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.base import DeviceInterrupted
from drivers.sim.render import RenderCancelled
from drivers.stereo import imaging
from drivers.stereo.errors import is_cancelled
from rvs_params import Settings, param

from .backend import BACKENDS, NAME
from .rig import PairRig

TARGET_GREY = 110  # DN: the pair's auto exposure aims the left image's mean here, as MER's hazcams autoexpose


@dataclass
class SimHazcamSettings(Settings):
    """drivers.hazcam keys of the simulated pairs."""

    seed: int = param(0, "sim: sensor noise seed", min=0, max=2**63 - 1)
    sim_noise: bool = param(True, "sim: shot + read noise")
    sim_scene: str = param("marsyard", "sim: the scene of pairs used with no shared world (scripts)")
    sim_readout: float = param(0.1, "sim: a pair's readout after its exposure, on the simulated clock, for a frame "
                               "taken standing (one taken while the rover rolls overlaps the drive)", unit="s",
                               min=0.0, max=10.0)


@BACKENDS.backend("sim")
class SimHazcams:
    settings = SimHazcamSettings

    def __init__(self, config: Any, world: Any = None) -> None:
        self.world = world
        self.scene = config.sim_scene
        self.seed = int(config.seed)
        self.readout = float(config.sim_readout)
        self.sensor = imaging.SensorModel(noise=bool(config.sim_noise))
        self._lock = threading.Lock()  # the noise generators
        self._rngs: dict[str, np.random.Generator] = {}

    def open(self, cameras: tuple[str, ...]) -> None:
        if self.world is None:
            from drivers.sim.world import World  # the default world only when nobody shared one

            self.world = World.from_scene(self.scene, seed=self.seed)
        with self._lock:
            self._rngs = {c: np.random.default_rng([self.seed, i]) for i, c in enumerate(cameras)}

    def close(self) -> None:
        pass

    def check(self, cameras: tuple[str, ...]) -> dict[str, Any]:
        return {c: {"responding": True} for c in cameras}

    def capture(self, rig: PairRig, cancel: Any = None) -> tuple[np.ndarray, np.ndarray, float]:
        world = self.world
        stamp = world.clock.now()
        T_world_rover = world.T_world_rover()  # read once: both cameras at one instant

        def stop() -> bool:
            return is_cancelled(cancel)

        w, h = rig.size
        try:
            views = [world.render(rig.K, w, h, T_world_rover @ T, cancel=None if cancel is None else stop)
                     for T in (rig.T_rover_left, rig.T_rover_right)]
        except RenderCancelled:
            raise DeviceInterrupted(NAME, "grab cancelled while the pair was exposed") from None
        light = imaging.Lighting(world.sun.azimuth_deg, world.sun.elevation_deg)
        optics = world.optics
        rads = []
        for view in views:
            rad = imaging.radiance(view.albedo, view.normal, np.isfinite(view.depth), light, view.sunlit)
            rads.append(imaging.vignette(imaging.lens_blur(rad, optics.blur_sigma_px), rig.K, optics.vignetting))
        shutter = imaging.auto_shutter(rads[0], TARGET_GREY, 0.0, self.sensor)  # one exposure for the pair
        with self._lock:
            rng = self._rngs.get(rig.camera)
            left, right = (imaging.jpeg(imaging.expose(rad, shutter, 0.0, self.sensor, rng), optics.jpeg_quality)
                           for rad in rads)
        if not world.rolling:  # standing, the frame's exposure and readout are the rover's time
            world.clock.sleep(shutter / 1e6 + self.readout, what="hazcam frames")
        return left, right, stamp
