"""Typed blocks of a scene file that say how harsh the simulated world looks: ``sun``, ``albedo``
and ``optics``.

The geometry sections of a scene (terrain primitives, objects, rover) are free-form lists; these
three are plain settings, so they are declared with :func:`rvs_params.param` like every other
setting (type, range, help, default in one place; unknown keys refused with the known ones). A
scene that leaves a block out gets the defaults below, which are the simulator as it was before
the harsh flavour existed: a sun at azimuth 200, elevation 45 without cast shadows, procedural
albedo, an ideal lens and no compression. ``config/scenes/marsyard_harsh.yaml`` turns them on.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from rvs_params import Settings, param


@dataclass
class SunSettings(Settings):
    """The scene's sun: where shading and cast shadows come from (the stereo cameras' light
    follows it unless drivers.stereo.sim_sun_* override it)."""

    azimuth_deg: float = param(200.0, "direction the sunlight comes from, global frame, CCW from +x", unit="deg",
                               min=-360.0, max=360.0)
    elevation_deg: float = param(45.0, "sun elevation above the horizon", unit="deg", min=1.0, max=90.0)
    shadows: bool = param(False, "cast shadows of the terrain (rocks, crater rims, slopes) on the terrain")


@dataclass
class AlbedoSettings(Settings):
    """Where the terrain's reflectance texture comes from. ``mars`` modulates the terrain's mean
    albedo (``terrain.albedo``) with a texture quilted from real Mars navigation-camera frames
    instead of the procedural fractal speckle, so stereo matches real ground statistics."""

    source: str = param("procedural", "procedural (fractal speckle) or mars (tiles of real Mars frames)",
                        choices=("procedural", "mars"))
    texture: str = param("mars_albedo.png", "texture file (8-bit PNG, 128 = the mean): next to the scene or "
                         "in drivers/sim/data")
    texel_m: float = param(0.008, "ground size of one texture pixel", unit="m", min=1e-4, max=1.0)
    contrast: float = param(1.0, "scale of the texture's deviations from its mean (1: as the frames show)",
                            min=0.0, max=3.0)
    detail: bool = param(True, "also use the texture as the renderer's sub-cell detail (instead of noise)")


@dataclass
class OpticsSettings(Settings):
    """What the simulated stereo cameras' lenses and encoder do to the image (the sensor's shot and
    read noise are drivers.stereo.sim_* keys). All off by default: an ideal lens, raw frames."""

    vignetting: float = param(0.0, "share of light lost in the image corners (cos^4-shaped falloff)", min=0.0,
                              max=0.95)
    blur_sigma_px: float = param(0.0, "lens blur: Gaussian sigma (defocus, diffraction)", unit="px", min=0.0,
                                 max=10.0)
    jpeg_quality: int = param(0, "JPEG-compress each frame at this quality (1-100; 0: raw)", min=0, max=100)


@dataclass
class SceneLook:
    """The three blocks of one scene, read from its spec."""

    sun: SunSettings
    albedo: AlbedoSettings
    optics: OpticsSettings

    @classmethod
    def from_spec(cls, spec: dict[str, Any]) -> SceneLook:
        """Each block typed and checked (an unknown key or a bad value names the scene and block)."""
        name = spec.get("name", "scene")
        blocks = {key: spec[key] if key in spec else None for key in ("sun", "albedo", "optics")}
        return cls(
            sun=SunSettings.from_mapping(blocks["sun"], where=f"scene {name}, sun"),
            albedo=AlbedoSettings.from_mapping(blocks["albedo"], where=f"scene {name}, albedo"),
            optics=OpticsSettings.from_mapping(blocks["optics"], where=f"scene {name}, optics"),
        )
