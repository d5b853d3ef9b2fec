"""What the server keeps of the terrain between requests, and the recovery sets of a break.

The current maps are shared by many commands (dem-* write them, dem-update merges into them,
check-move, navigate and the monitors read them, break saves them, recover restores them), so
they live here rather than in whichever command module happened to need them first. They are
read and written from job threads, monitor threads and the event loop: every access goes
through :class:`CurrentMaps`, whose one lock keeps the layers, their files and the views left
for the next update consistent with each other.
"""

from __future__ import annotations

import shutil
import threading
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import structlog
import yaml

from prox_workflows.grid import Layers, median_near, read_geotiff
from prox_workflows.products import write_yaml_atomic

from .bus import tapped_call
from .protocol import Fixed, ProtocolError, valid_stem

if TYPE_CHECKING:
    from .app import App
    from .bus import Bus

log = structlog.get_logger("rvs")


class CurrentMaps:
    """The current DEM's layers (one grid), the files they were written to (layer -> path under
    the data directory, what a recovery set copies) and the views that a stopped acquisition left
    behind for the next dem-update. Thread-safe; the three change together or not at all. A new
    or restored DEM is published on ``bus`` (Foxglove's grids, a recording) once the lock is let go."""

    def __init__(self, bus: Bus | None = None) -> None:
        self._bus = bus
        self._lock = threading.RLock()
        self._layers: Layers | None = None
        self._name: str | None = None
        self._files: dict[str, str] = {}
        self._pending: list[Any] = []

    @property
    def layers(self) -> Layers | None:
        """The current DEM and its companion layers, or None before the first DEM."""
        with self._lock:
            return self._layers

    @property
    def name(self) -> str | None:
        with self._lock:
            return self._name

    def files(self) -> dict[str, str]:
        """A copy of the current products' paths (relative to the data directory)."""
        with self._lock:
            return dict(self._files)

    def for_update(self) -> tuple[Layers | None, list[Any]]:
        """The DEM an update merges into and the views kept for it, read together."""
        with self._lock:
            return self._layers, list(self._pending)

    def updatable(self) -> bool:
        """Whether dem-update has anything to merge into: a DEM, or views a break left."""
        with self._lock:
            return self._layers is not None or bool(self._pending)

    def replace(self, layers: Layers, name: str, files: dict[str, str]) -> None:
        """A new current DEM, written as ``files``; the views kept for an update are used up."""
        with self._lock:
            self._layers, self._name, self._files, self._pending = layers, name, dict(files), []
        if self._bus is not None:
            self._bus.publish("maps", layers=layers, name=name)

    def restore(self, layers: Layers, files: dict[str, str]) -> None:
        """The maps of a recovery set; views kept for an update stay (they are newer)."""
        with self._lock:
            self._layers, self._files = layers, dict(files)
            name = self._name
        if self._bus is not None:
            self._bus.publish("maps", layers=layers, name=name)

    def keep_views(self, views: list[Any]) -> None:
        """The views a stopped acquisition got, for the next dem-update to start from."""
        with self._lock:
            self._pending = list(views)


def ground_height(layers: Layers | None, x: float, y: float) -> float:
    """The DEM's height under (x, y): the median over about a metre, 0 where nothing is known."""
    if layers is None:
        return 0.0
    z = median_near(layers["dem"], layers.geometry, x, y)
    return 0.0 if z is None else z


def current_pose(app: App, call: Callable[..., Any] | None = None
                 ) -> tuple[float, float, float, float, float, float]:
    """x, y, heading, the ground height under the rover (from the current DEM if known), and the
    roll and pitch its IMU or the GNC's pose report gives (level where neither does): the GNC
    reports a planar pose, and a scan's points need the height and the body's tilt too.

    ``call`` makes the attitude read (a monitor's or job's device call); by default it is tapped
    like a frame, so a recording holds the tilt its scans were placed with. A monitor passes its
    own, so that a replay holds the read back in its recorded turn as it does the frames."""
    p = app.pose
    rover = app.devices.devices.get("rover")
    attitude = None
    if rover is not None:
        attitude = call(rover.attitude) if call is not None else tapped_call(app.bus, rover.attitude)
    roll, pitch = (float(attitude[0]), float(attitude[1])) if attitude is not None else (0.0, 0.0)
    return (p.x, p.y, p.heading, ground_height(app.maps.layers, p.x, p.y), roll, pitch)


# ------------------------------------------------------------------ recovery sets


class RecoverySets:
    """The recovery sets under ``<data>/recovery``: written by break, read by recover and
    ``--recover``. A set is written into a temporary folder and renamed, so it is either complete
    or absent; ``last`` is the newest complete one (what status shows)."""

    def __init__(self, data_dir: Path, rel: Callable[[Path], str]) -> None:
        self.data_dir = data_dir
        self.root = data_dir / "recovery"
        self._rel = rel
        self._lock = threading.Lock()
        self._last: str | None = None
        self._find_last()

    @property
    def last(self) -> str | None:
        return self._last

    def _find_last(self) -> None:
        """Temp folders of a set that a crash cut short are removed here, at start."""
        if not self.root.is_dir():
            return
        for stray in self.root.glob(".*.tmp"):
            shutil.rmtree(stray, ignore_errors=True)
            log.warning("recovery_tmp_removed", folder=stray.name)
        sets = sorted(p for p in self.root.iterdir() if (p / "manifest.yaml").is_file())
        if sets:
            self._last = self._rel(sets[-1])

    def write(self, manifest: dict[str, Any], maps: dict[str, str]) -> str:
        """Store ``manifest`` plus copies of the ``maps`` files; returns the set's folder.

        A failure removes the temporary folder before it is raised."""
        with self._lock:
            stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S_%fZ")
            self.root.mkdir(parents=True, exist_ok=True)
            tmp = self.root / f".{stamp}.tmp"
            tmp.mkdir()
            try:
                copied: dict[str, str] = {}
                for layer, rel in maps.items():
                    src = self.data_dir / rel
                    if src.is_file():
                        (tmp / "maps").mkdir(exist_ok=True)
                        shutil.copy2(src, tmp / "maps" / src.name)
                        copied[layer] = f"maps/{src.name}"
                write_yaml_atomic(tmp / "manifest.yaml", {**manifest, "maps": copied})
                final = self.root / stamp
                tmp.rename(final)
            except BaseException:
                shutil.rmtree(tmp, ignore_errors=True)
                raise
            self._last = self._rel(final)
            return self._last

    def folder(self, which: str) -> Path:
        """The folder of a recovery set (``last`` or a name under recovery/), checked to hold one."""
        if which == "last":
            if not self._last:
                raise ProtocolError("E_DATA", "there is no recovery set under the data directory")
            folder = self.data_dir / self._last
        else:
            if not valid_stem(which):
                raise ProtocolError("E_ARG", "-set is last or the name of a folder under recovery/")
            folder = self.root / which
        if not (folder / "manifest.yaml").is_file():
            raise ProtocolError("E_DATA", f"no recovery set at {self._rel(folder)}; status shows the last one")
        return folder


def load_layers(paths: dict[str, Path], check: Callable[[], None] = lambda: None) -> Layers:
    """Read a DEM's layer GeoTIFFs back into one Layers (they share the DEM's grid); ``check`` runs
    before each file, so a break stops a long read between layers."""
    if "dem" not in paths:
        raise ProtocolError("E_DATA", "the recovery set holds no DEM layer")
    check()
    dem, geometry = read_geotiff(paths["dem"])
    layers = Layers(geometry, {"dem": dem})
    for layer, path in paths.items():
        if layer in ("dem", "mesh") or path.suffix != ".tif":
            continue
        check()
        image, g = read_geotiff(path)
        if g == geometry:
            layers[layer] = image
    return layers


def load_recovery(app: App, which: str, check: Callable[[], None] = lambda: None) -> dict[str, Any]:
    """Restore pose and maps from a recovery set; returns what was restored (recover's OK).

    Everything is read before anything is applied, and ``check`` (the job's break check) runs
    between the reads: an interrupted recover leaves the pose and the maps as they were."""
    folder = app.recovery.folder(which)
    manifest = yaml.safe_load((folder / "manifest.yaml").read_text()) or {}
    pose = manifest.get("pose") or {}
    maps = {layer: folder / rel for layer, rel in (manifest.get("maps") or {}).items()}
    layers = load_layers(maps, check) if maps else None
    check()
    app.set_pose(float(pose.get("x", 0.0)), float(pose.get("y", 0.0)), float(pose.get("heading", 0.0)),
                 source="recovery")
    out: dict[str, Any] = {"recovery": app.rel(folder), "pose": [Fixed(app.pose.x, 3), Fixed(app.pose.y, 3),
                                                                    Fixed(app.pose.heading, 2)]}
    if layers is not None:
        app.maps.restore(layers, {layer: app.rel(path) for layer, path in maps.items()})
        out["cells"] = int(np.isfinite(layers["dem"]).sum())
    job = manifest.get("job") or {}
    out["interrupted_job"] = job.get("command")
    return out
