"""The parameter classes of the workflow scripts for what no single registered step owns: settings
several steps share (the cell size), and the acquisition the server supplies (views, ranges, the
sensors' noise models). A step's own settings class lives beside the step (``SpikeRemoval`` in
steps/dem.py) and joins every script that calls it (:func:`prox_workflows.engine.script_parameters`).

A script names its class (``params: dem``) and reads the values as ``$cell``; the server's
command config classes derive from the composed class, so a parameter's default, range, unit and
help are written once: ``help dem-full-tof`` and ``rvs-prox dem --help`` print the same list.
Fields with ``option=False`` are settings (``config -module dem_full_tof -set spike_jump=0.04``,
``rvs-prox --set``), not request options.
"""

from __future__ import annotations

from dataclasses import dataclass

from rvs_params import Settings, param

from .params import parameters


@parameters("dem")
@dataclass
class DemParams(Settings):
    """A DEM from views (ToF by default): acquisition, DemImport, DemMosaik, holes, spikes."""

    range: list[float] = param([-150.0, 150.0, -50.0, -15.0], "view range pan_min,pan_max,tilt_min,tilt_max",
                               unit="deg", length=4, min=-360.0, max=360.0, ordered=True)
    name: str = param("", "stem of the products (default dem_<UTC time>)", stem=True)
    cell: float = param(0.02, "DEM cell size", unit="m", min=0.005, max=1.0)
    overlap: float = param(0.2, "share of the field of view that neighbouring views overlap", min=0.0, max=0.9)
    integrate: int = param(4, "ToF frames integrated per view", min=1, max=100)
    confidence: float = param(0.3, "discard ToF pixels below this confidence", min=0.0, max=1.0)
    max_range: float = param(4.5, "ignore points farther than this from the sensor", unit="m", min=0.3, max=30.0)
    min_reflectivity: float = param(0.1, "drop ToF returns weaker than this share of the view's median "
                                    "amplitude x range^2 (phase-wrapped far surfaces)", min=0.0, max=1.0,
                                    option=False)
    wrap_check: bool = param(True, "one more ToF frame per view at half the modulation frequency: drop returns "
                             "from beyond the unambiguous range (a far wall read as a phantom close by)",
                             option=False)
    rule: str = param("fuse", "how views and the current DEM merge", choices=("fuse", "max", "newest"))
    fill_radius: float = param(0.06, "fill holes up to this radius", unit="m", min=0.0, max=2.0)
    mesh: bool = param(True, "also write a textured mesh (PLY)")
    # ToF-stereo fusion (-sensor fused): each sensor's per-point height noise model, one standard
    # deviation per cause (prox_workflows/algorithms/noise.py), fitted to the simulator's truth by
    # ``python -m tools.bench.fusion --calibrate``, which prints these values and predicted vs
    # measured error per range band; a real head would be calibrated the same way on a surveyed site
    tof_noise_floor: float = param(0.0, "ToF height noise: floor", unit="m", min=0.0, max=1.0, option=False)
    tof_noise_shot: float = param(3.491, "ToF height noise: phase noise x amplitude (falls with the amplitude)",
                                  unit="m*counts", min=0.0, max=1000.0, option=False)
    tof_noise_range: float = param(0.0, "ToF height noise: per metre of range", unit="m/m", min=0.0, max=1.0,
                                   option=False)
    tof_noise_incidence: float = param(0.0002658, "ToF height noise: per metre of range x tan(incidence)",
                                       unit="m/m", min=0.0, max=1.0, option=False)
    tof_noise_edge: float = param(0.5697, "ToF height noise: share of the height jump to the pixel's neighbours "
                                  "(mixed pixels on depth edges)", min=0.0, max=10.0, option=False)
    tof_noise_slope: float = param(0.0005963, "ToF height noise: per unit of the ground's slope at the pixel "
                                   "(the cell's sampling of steep ground)", unit="m", min=0.0, max=1.0, option=False)
    tof_noise_multipath: float = param(0.01068, "ToF height noise: per metre of range x share of wall pixels nearby "
                                       "(multipath)", unit="m/m", min=0.0, max=1.0, option=False)
    stereo_noise_floor: float = param(0.0, "stereo height noise: floor", unit="m", min=0.0, max=1.0, option=False)
    stereo_noise_disparity: float = param(0.1324, "stereo height noise: disparity sigma (depth error z^2 "
                                          "sigma / (b f))", unit="px", min=0.0, max=100.0, option=False)
    stereo_noise_texture: float = param(0.1535, "stereo height noise: disparity sigma x grey-level spread (grows "
                                        "where texture is weak)", unit="px*grey", min=0.0, max=1000.0, option=False)
    stereo_noise_incidence: float = param(6.644e-05, "stereo height noise: per metre of range x tan(incidence)",
                                          unit="m/m", min=0.0, max=1.0, option=False)
    stereo_noise_edge: float = param(0.3692, "stereo height noise: share of the height jump to the pixel's "
                                     "neighbours (occlusion edges)", min=0.0, max=10.0, option=False)
    stereo_noise_slope: float = param(0.002353, "stereo height noise: per unit of the ground's slope at the pixel",
                                      unit="m", min=0.0, max=1.0, option=False)
    stereo_noise_multipath: float = param(0.02663, "stereo height noise: per metre of range x share of wall "
                                          "pixels nearby", unit="m/m", min=0.0, max=1.0, option=False)


@parameters("dem_stereo")
@dataclass
class DemStereoParams(DemParams):
    """dem-full / dem-update: the DEM parameters, plus the stereo ones."""

    sensor: str = param("stereo", "sensor: the stereo pair, or stereo and ToF fused", choices=("stereo", "fused"))
    max_range: float = param(6.0, "ignore points farther than this from the sensor", unit="m", min=0.3, max=30.0)
    stereo_scale: float = param(1.0, "matching scale (0.5: half resolution, faster)", min=0.25, max=1.0,
                                option=False)


@parameters("dem_import")
@dataclass
class DemImportParams(Settings):
    """DemImport of point clouds into one DEM (``rvs-dem-import``)."""

    cell: float = param(0.02, "DEM cell size", unit="m", min=0.0001, max=100.0)
    height: str = param("mean", "what the dem layer holds: the (information-weighted) mean height of the "
                        "cell's points, or the greatest (the thesis's direct rule)", choices=("mean", "max"))
