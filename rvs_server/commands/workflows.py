"""Workflow commands: ``prox -script NAME -from PATH -set "k=v ..."`` re-runs a recorded DEM job.

The server's twin of ``rvs-prox dem --from`` (prox_workflows.reprocess): the job's folder under
the data directory (views, .cal, sidecars with the parameters used) is read back and run through
the same chain as the live scan, with the recorded parameters and the ``-set`` overrides, as a
job (ACK, PROGRESS per phase, break stops it at the next step), and the products go to
``<job dir>/reprocessed/``. ``-from`` is confined to the data directory: the server must not be
made to read (or write beside) anything a client could name outside it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from prox_workflows.engine import Cancelled, WorkflowError
from prox_workflows.grid import read_geotiff
from prox_workflows.reprocess import (
    OFFLINE_SCRIPTS,
    RecordedJob,
    ReprocessError,
    find_job,
    job_params,
    parse_overrides,
    reprocess,
)
from rvs_params import ParamSpec

from ..config import ModuleConfig, param
from ..jobs import Interrupted, Job
from ..protocol import Fixed, ProtocolError
from ..table import HARDWARE, command

if TYPE_CHECKING:
    from ..app import App

@dataclass
class ProxConfig(ModuleConfig):
    """prox: re-run a recorded DEM job offline with other parameters.

    ``from`` is a Python keyword, so the field is ``from_`` and :meth:`specs` declares it as
    ``from``: the option on the wire is ``-from``, as ``rvs-prox --from`` names it; the option
    parser sets it through the ``from`` property below.
    """

    module: ClassVar[str] = "prox"
    script: str = param("dem", "the workflow script to run offline", choices=tuple(OFFLINE_SCRIPTS))
    from_: str = param("", "the recorded DEM job, relative to the data directory: dem/<name> or "
                           "dem/<name>_views", required=True)
    set: str = param("", "parameters over the recorded ones: \"cell=0.05 fill_radius=0.1\"")

    @classmethod
    def specs(cls) -> dict[str, ParamSpec]:
        cached = cls.__dict__.get("_renamed")
        if cached is None:
            cached = {("from" if n == "from_" else n): (replace(s, name="from") if n == "from_" else s)
                      for n, s in super().specs().items()}
            cls._renamed = cached  # type: ignore[attr-defined]
        return cached

    def as_dict(self) -> dict[str, Any]:
        """As the wire names the keys (``from``), for ``config -module prox`` and the logs."""
        return {("from" if k == "from_" else k): v for k, v in super().as_dict().items()}

    @classmethod
    def from_mapping(cls, data: Any = None, *, where: str = "") -> ProxConfig:
        """config/prox.yaml and :meth:`as_dict` say ``from``; the field is ``from_``."""
        if isinstance(data, dict) and "from" in data:
            data = {("from_" if k == "from" else k): v for k, v in data.items()}
            cfg = super().from_mapping({k: v for k, v in data.items() if k != "from_"}, where=where)
            cfg.from_ = str(data["from_"])
            return cfg
        return super().from_mapping(data, where=where)


ProxConfig.__annotations__.pop("_renamed", None)
setattr(ProxConfig, "from", property(lambda self: self.from_, lambda self, value: setattr(self, "from_", value)))


def confined(app: App, raw: str) -> Path:
    """``raw`` as a path inside the data directory (symlinks resolved), else E_ARG: no ``..``
    out of it, no absolute path elsewhere."""
    root = app.data_dir.resolve()
    try:
        path = (root / raw).resolve()
        path.relative_to(root)
    except (ValueError, OSError):
        raise ProtocolError("E_ARG", f"-from {raw[:60]!r} is outside the data directory; name a job under it "
                                     "(dem/<name>)") from None
    return path


def _recorded(app: App, cfg: ProxConfig) -> tuple[RecordedJob, dict[str, Any]]:
    path = confined(app, cfg.from_)
    try:
        job = find_job(path)
    except ReprocessError as exc:
        root = str(app.data_dir.resolve()) + "/"  # paths on the wire are relative to the data directory
        raise ProtocolError("E_DATA", f"-from: {str(exc).replace(root, '')}") from None
    confined(app, str(job.views))  # a views folder that is a symlink out of the data directory
    try:
        overrides = parse_overrides(cfg.set)
        job_params(job, overrides)
    except ReprocessError as exc:
        raise ProtocolError("E_ARG", f"-set: {exc}") from None
    return job, overrides


def _check_prox(app: App, cfg: ProxConfig) -> None:
    _recorded(app, cfg)


@command("prox", job=True, klass=HARDWARE, config=ProxConfig, check=_check_prox,
         help="re-run a recorded DEM job offline (-from dem/<name>) with its recorded parameters and -set "
              "overrides; products in <job dir>/reprocessed/")
def prox(job: Job, cfg: ProxConfig) -> dict[str, Any]:
    app = job.app
    recorded, overrides = _recorded(app, cfg)
    try:
        result = reprocess(recorded, overrides, script=cfg.script, made_by=job.command, progress=job.progress,
                           cancelled=lambda: job.cancelled)
        job.check()
    except Cancelled:
        raise Interrupted(f"prox job {job.id} was interrupted; no product was replaced") from None
    except (ReprocessError, WorkflowError) as exc:
        raise ProtocolError("E_DATA", f"{recorded.name}: {exc}") from None
    files = result["files"]
    rel = {layer: app.rel(path) for layer, path in files.items()}
    out: dict[str, Any] = {k: rel[k] for k in ("dem", "ortho", "hazard", "slope", "step", "roughness",
                                               "traversability", "mesh") if k in rel}
    dem, _ = read_geotiff(files["dem"])
    defined = np.isfinite(dem)
    out.update(cells=int(defined.sum()), coverage=Fixed(float(defined.mean()), 3), views=result["views"])
    return out
