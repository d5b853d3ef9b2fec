"""Offline reprocessing: a DEM job's folder is enough to run it again.

A dem job leaves ``<dir>/<name>_views/`` (coordinate images, ``.aux.tiff`` companions, ``.cal``
files, the image list, ``<name>_scan.yaml`` with the pose and rover mask) and its products
``<dir>/<name>_*.tif`` whose YAML sidecars record every parameter the job used and the
Dem2Hazard thresholds (``meta.dem2hazard``). :func:`reprocess` reads those back, lets the caller
override some (``--set cell=0.05``) and runs the ``dem_views`` script, the very chain the server
ran, so the same parameters give byte-identical products and only the overridden ones differ.

Products go to ``<dir>/reprocessed/`` (or an explicit ``out_dir``), never over the job's own
products: those stay the record of what the rover made, and the re-run's outputs must be
distinguishable from its inputs (the batch skips an input whose outputs are newer than it). The
products are written to a staging folder first and moved into place one by one with the DEM
last, so a crash leaves the previous complete set or a DEM older than its companions, which the
batch's freshness check treats as not done.

Used by ``rvs-prox dem --from``, the server's ``prox`` command and ``rvs-prox batch``; it imports
neither the server nor the drivers.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from rvs_params import SettingError, Settings, assignments

from .algorithms.dem2hazard import HazardParams
from .engine import parameters_of, run_workflow
from .parameters import DemParams, DemStereoParams

# The scripts --from can run: a script that acquires (dem) runs offline as its recorded-views
# twin (dem_views); the twin itself is accepted under its own name.
OFFLINE_SCRIPTS: dict[str, str] = {"dem": "dem_views", "dem_views": "dem_views"}
OUT_FOLDER = "reprocessed"  # beside the job's products, never over them
STEREO_COMMANDS = ("dem-full", "dem-update")


class ReprocessError(ValueError):
    """A path that is not a recorded DEM job, or a parameter the job's class refuses."""


@dataclass
class RecordedJob:
    """What a DEM job left on disk: its views folder, its DEM product and the parameters used."""

    views: Path
    name: str
    dem: Path | None = None
    made_by: str = ""
    parameters: dict[str, Any] = field(default_factory=dict)
    hazard: dict[str, Any] | None = None

    @property
    def folder(self) -> Path:
        """The folder holding the job's products and its views folder."""
        return self.views.parent

    def input_files(self) -> list[Path]:
        """Every file a re-run reads: the views folder's files and the DEM's sidecar."""
        files = [p for p in self.views.iterdir() if p.is_file()]
        if self.dem is not None and self.dem.with_suffix(".yaml").is_file():
            files.append(self.dem.with_suffix(".yaml"))
        return files

    def newest_input(self) -> float:
        return max((p.stat().st_mtime for p in self.input_files()), default=0.0)

    def param_class(self) -> type[Settings]:
        """The job's parameter class: the stereo one for dem-full/dem-update (their max_range
        default differs), the ToF one otherwise."""
        own = DemStereoParams if self.made_by in STEREO_COMMANDS or "sensor" in self.parameters else DemParams
        return parameters_of(OFFLINE_SCRIPTS["dem"], own)


def find_job(path: str | Path) -> RecordedJob:
    """The recorded job at ``path``: its views folder (``site_views``), its stem (``dem/site``),
    one of its products (``dem/site_dem.tif``) or a folder holding exactly one views folder."""
    path = Path(path)
    views: Path | None = None
    if path.is_dir() and any(path.glob("*_images.csv")):
        views = path
    elif path.with_name(f"{path.name}_views").is_dir():
        views = path.with_name(f"{path.name}_views")
    elif path.is_file():  # one of the job's products (site_dem.tif, site_hazard.png, site_dem.yaml ...)
        stem = path.name.split(".")[0]
        while "_" in stem and views is None:
            stem = stem.rsplit("_", 1)[0]
            if path.with_name(f"{stem}_views").is_dir():
                views = path.with_name(f"{stem}_views")
    elif path.is_dir():
        found = [p for p in path.glob("*_views") if p.is_dir()]
        if len(found) == 1:
            views = found[0]
        elif len(found) > 1:
            raise ReprocessError(f"{path} holds {len(found)} DEM jobs ({', '.join(p.name for p in found[:5])}); "
                                 "name one (its <name>_views folder or <dir>/<name>)")
    if views is None or not any(views.glob("*_images.csv")):
        raise ReprocessError(f"{path}: not a DEM job's folder (want <dir>/<name>_views with *_images.csv, "
                             "or <dir>/<name> beside it)")
    name = views.name[: -len("_views")] if views.name.endswith("_views") else views.name
    job = RecordedJob(views=views, name=name)
    dem = views.parent / f"{name}_dem.tif"
    sidecar = dem.with_suffix(".yaml")
    if sidecar.is_file():
        info = yaml.safe_load(sidecar.read_text()) or {}
        job.dem = dem
        job.made_by = str(info.get("made_by") or "")
        job.parameters = dict(info.get("parameters") or {})
        hazard = (info.get("meta") or {}).get("dem2hazard")
        if isinstance(hazard, dict):
            known = HazardParams.specs()
            job.hazard = {k: v for k, v in hazard.items() if k in known}
    return job


def parse_overrides(items: list[str] | str | None) -> dict[str, str]:
    """``["cell=0.05", ...]`` or ``"cell=0.05 fill_radius=0.1"`` -> ``{"cell": "0.05", ...}``, as a
    ReprocessError (the request's or the command line's fault) when a word is not key=value."""
    try:
        return assignments(items, flag="set")
    except SettingError as exc:
        raise ReprocessError(exc.message) from None


def job_params(job: RecordedJob, overrides: dict[str, Any] | None = None) -> tuple[type[Settings], dict[str, Any]]:
    """The recorded parameters (those the job's class knows), then the overrides, each checked
    by the class's own rules; an unknown key is refused with the list of known ones."""
    cls = job.param_class()
    specs = cls.specs()
    params: dict[str, Any] = {k: v for k, v in job.parameters.items() if k in specs}
    for key, raw in (overrides or {}).items():
        spec = specs.get(key)
        if spec is None:
            raise ReprocessError(f"unknown parameter '{key}' for {job.name}; known: {', '.join(specs)}")
        try:
            params[key] = spec.parse(str(raw)) if isinstance(raw, str) else raw
        except SettingError as exc:
            raise ReprocessError(exc.message) from None
    params.setdefault("name", job.name)
    if not params["name"]:
        params["name"] = job.name
    return cls, params


def output_dir(job: RecordedJob, out_dir: str | Path | None = None) -> Path:
    return Path(out_dir) if out_dir is not None else job.folder / OUT_FOLDER


def is_current(job: RecordedJob, out_dir: str | Path | None = None, name: str | None = None) -> bool:
    """Are the re-run's products newer than every input (so a batch re-run can skip it)?"""
    dem = output_dir(job, out_dir) / f"{name or job.name}_dem.tif"
    return dem.is_file() and dem.stat().st_mtime > job.newest_input()


def reprocess(
    path: str | Path | RecordedJob,
    overrides: dict[str, Any] | None = None,
    out_dir: str | Path | None = None,
    *,
    script: str = "dem",
    made_by: str = "rvs-prox --from",
    progress: Callable[..., None] | None = None,
    cancelled: Callable[[], bool] | None = None,
) -> dict[str, Any]:
    """Run a recorded DEM job again with its recorded parameters and ``overrides``.

    Returns ``{"files": layer -> path, "views": n, "out_dir": Path, "parameters": {...}}``.
    """
    offline = OFFLINE_SCRIPTS.get(script)
    if offline is None:
        raise ReprocessError(f"--from reprocesses a DEM job; script {script!r} has no offline form "
                             f"(use one of {', '.join(OFFLINE_SCRIPTS)})")
    job = path if isinstance(path, RecordedJob) else find_job(path)
    cls, params = job_params(job, overrides)
    target = output_dir(job, out_dir)
    target.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{params['name']}.", suffix=".tmp", dir=target))
    try:
        workspace = {
            "views_folder": job.views, "base": None, "hazard": job.hazard, "out_dir": staging,
            "views_dir": os.path.relpath(job.views, target), "made_by": made_by, "parameters": params,
        }
        ws, _ = run_workflow(offline, params, workspace, progress=progress, cancelled=cancelled, param_cls=cls)
        files = _publish(staging, target, params["name"], ws["files"])
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return {"files": files, "views": len(ws["views"]), "out_dir": target, "parameters": params,
            "update": job.made_by.startswith("dem-update")}


def _publish(staging: Path, target: Path, name: str, written: dict[str, Path]) -> dict[str, Path]:
    """Move the staged products into ``target``, the DEM GeoTIFF last: it is the mark that the
    whole set is there (:func:`is_current` reads its time)."""
    dem_name = f"{name}_dem.tif"
    staged = sorted(p for p in staging.iterdir() if p.is_file())
    for p in sorted(staged, key=lambda p: p.name == dem_name):
        os.replace(p, target / p.name)
    return {layer: target / Path(p).name for layer, p in written.items()}
