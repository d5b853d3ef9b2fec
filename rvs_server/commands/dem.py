"""DEM commands: dem-full-tof, dem-update-tof, dem-full, dem-update and recover.

Each runs the DEM scan (:mod:`rvs_server.scanning`): views through the ``dem`` workflow script,
products under ``<data>/dem/``, the result the current DEM (what dem-update merges into, what
check-move and navigate read).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from drivers.stereo.modes import RESOLUTIONS
from prox_workflows.algorithms.dem2hazard import HazardParams
from prox_workflows.engine import parameters_of, validate
from prox_workflows.parameters import DemStereoParams

from ..config import ModuleConfig, param, standalone
from ..jobs import Job
from ..maps import load_recovery
from ..scanning import DEM_INPUTS, DEM_SCRIPT, ScanOptions, check_update, run_dem
from ..table import CONTROL, HARDWARE, command

# The parameters are declared once, in the dem script's own class (prox_workflows.parameters) and
# its steps' settings classes, composed by parameters_of (the dem script and rvs-prox read the
# same declarations); these add the module name the server's configuration (config/<module>.yaml,
# config -module, help) knows them by.
DemScriptParams = parameters_of(DEM_SCRIPT)
DemStereoScriptParams = parameters_of(DEM_SCRIPT, DemStereoParams)


@standalone
@dataclass
class Dem2HazardConfig(HazardParams, ModuleConfig):
    """config/dem2hazard.yaml: the rover's limits that turn a DEM into hazard maps."""

    module: ClassVar[str] = "dem2hazard"


@dataclass
class DemTofConfig(ScanOptions, DemScriptParams, ModuleConfig):
    module: ClassVar[str] = "dem_full_tof"


@dataclass
class DemUpdateTofConfig(DemTofConfig):
    module: ClassVar[str] = "dem_update_tof"


@dataclass
class DemStereoConfig(ScanOptions, DemStereoScriptParams, ModuleConfig):
    """dem-full / dem-update: the same options as the ToF commands, plus the stereo ones."""

    resolution: str = param("low", "stereo resolution mode", choices=tuple(RESOLUTIONS))

    module: ClassVar[str] = "dem_full"


@dataclass
class DemUpdateStereoConfig(DemStereoConfig):
    module: ClassVar[str] = "dem_update"


def validate_scripts() -> None:
    """Validate every command's workflow script against the command's config class and the
    server's inputs and steps; raises ScriptError (line and fix of each mistake)."""
    for cls in (DemTofConfig, DemStereoConfig):
        validate(DEM_SCRIPT, workspace=DEM_INPUTS, param_cls=cls)


@command("dem-full-tof", job=True, klass=HARDWARE, config=DemTofConfig,
         help="new DEM from ToF views over -range, with ortho-image and hazard maps")
def dem_full_tof(job: Job, cfg: DemTofConfig) -> dict[str, Any]:
    return run_dem(job, cfg, update=False)


@command("dem-update-tof", job=True, klass=HARDWARE, config=DemUpdateTofConfig, check=lambda app, cfg: check_update(app),
         help="as dem-full-tof, merged into the current DEM (which it may extend)")
def dem_update_tof(job: Job, cfg: DemUpdateTofConfig) -> dict[str, Any]:
    return run_dem(job, cfg, update=True)


@command("dem-full", job=True, klass=HARDWARE, config=DemStereoConfig,
         help="new DEM from stereo pairs (or -sensor fused: stereo and ToF) over -range, with ortho-image and hazard maps")
def dem_full(job: Job, cfg: DemStereoConfig) -> dict[str, Any]:
    return run_dem(job, cfg, update=False, sensor=cfg.sensor)


@command("dem-update", job=True, klass=HARDWARE, config=DemUpdateStereoConfig, check=lambda app, cfg: check_update(app),
         help="as dem-full, merged into the current DEM (which it may extend)")
def dem_update(job: Job, cfg: DemUpdateStereoConfig) -> dict[str, Any]:
    return run_dem(job, cfg, update=True, sensor=cfg.sensor)



# ------------------------------------------------------------------ recovery


@dataclass
class RecoverConfig(ModuleConfig):
    module: ClassVar[str] = "recover"
    set: str = param("last", "recovery set to load: last, or its folder under recovery/")


@command("recover", job=True, klass=CONTROL, config=RecoverConfig,
         check=lambda app, cfg: app.recovery.folder(cfg.set) and None,
         help="load a recovery set written by break: the pose and the maps it held (-set last or a folder)")
def recover(job: Job, cfg: RecoverConfig) -> dict[str, Any]:
    job.progress(0, 1, f"loading recovery set {cfg.set}")
    return load_recovery(job.app, cfg.set, job.check)
