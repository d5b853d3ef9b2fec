"""Campaign processing on Dask: a script fanned out over many recorded jobs, and one mosaic of them.

``rvs-prox batch SCRIPT --inputs 'campaign/*/dem/*' [--scheduler tcp://host:8786] [--workers N]``
finds the recorded DEM jobs the patterns name (a job is found from its views folder, its stem or
its DEM, so a pattern that matches all three finds it once) and runs :func:`reprocess` on each as
one Dask task: on a LocalCluster on this machine by default, on any cluster given its scheduler's
address (the workers must have this package installed and see the same paths). Each task writes
its products atomically beside its input (``<dir>/reprocessed/``) and returns a small
:class:`TaskResult`, never the arrays, so the scheduler moves kilobytes however big the DEMs are.
A failing job is reported with its error and the others go on; a job whose products are newer
than all its inputs is skipped, so a re-run after a failure redoes only what is missing.

``rvs-prox mosaic-campaign --inputs 'campaign/*/dem/reprocessed/*_dem.tif' -o campaign/mosaic``
(a folder, as ``rvs-prox dem --from -o`` takes: ``mosaic_dem.tif``, ``_variance``, ``_count`` in it)
fuses the site DEMs (DemMosaik's variance-weighted ``fuse``, sites in the order given) into one
grid written tile by tile into tiled GeoTIFFs: a tile reads only the sites that overlap its band
of rows, so memory is bounded by a band and its sites, not by the mosaic, which may be larger
than memory. A tile is the same as the same window of the mosaic made in memory (the fuse is per
cell; every site is resampled onto the same lattice).
"""

from __future__ import annotations

import glob
import math
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

from .algorithms.dem_mosaik import dem_mosaik, union_geometry
from .grid import GridGeometry, Layers, geo_tags, read_geotiff, read_geotiff_geometry
from .products import atomic_path, write_yaml_atomic
from .reprocess import (
    OUT_FOLDER,
    ReprocessError,
    find_job,
    is_current,
    reprocess,
)

# ------------------------------------------------------------------------------ inputs


def find_inputs(patterns: Sequence[str]) -> tuple[list[Path], list[str]]:
    """The recorded jobs the glob patterns match (each once, sorted), and what matched but is
    no job (a product folder, a stray file), so the caller can say what it left out."""
    seen: dict[Path, None] = {}
    ignored: list[str] = []
    for pattern in patterns:
        for hit in sorted(glob.glob(pattern, recursive=True)):
            p = Path(hit)
            if p.name == OUT_FOLDER or p.parent.name == OUT_FOLDER or p.name.startswith("."):
                continue
            try:
                views = find_job(p).views
            except ReprocessError:
                ignored.append(hit)
                continue
            seen.setdefault(views.resolve(), None)
    return sorted(seen), ignored


# ------------------------------------------------------------------------------ one task


@dataclass
class TaskResult:
    """What one task reports back: small and picklable (paths as text, no arrays)."""

    input: str
    status: str  # done, skipped, failed, planned
    seconds: float = 0.0
    files: dict[str, str] = field(default_factory=dict)
    error: str = ""


def run_one(views: str, script: str = "dem", overrides: dict[str, str] | None = None,
            out_dir: str | None = None, dry_run: bool = False) -> TaskResult:
    """One input's task: reprocess it, catching every failure into the result so one bad input
    never stops the batch (and the worker stays up). ``dry_run`` returns at once: what the
    10,000-input scheduling benchmark runs, to time the graph and not the steps."""
    if dry_run:
        return TaskResult(views, "planned")
    t0 = time.perf_counter()
    try:
        result = reprocess(views, overrides, out_dir, script=script, made_by=f"rvs-prox batch {script}")
    except Exception as exc:  # noqa: BLE001 - reported per input, the others go on
        last = traceback.extract_tb(exc.__traceback__)[-1:]
        where = f" ({Path(last[0].filename).name}:{last[0].lineno})" if last else ""
        return TaskResult(views, "failed", time.perf_counter() - t0, error=f"{type(exc).__name__}: {exc}{where}")
    return TaskResult(views, "done", time.perf_counter() - t0, {k: str(v) for k, v in result["files"].items()})


def serial(inputs: Sequence[Path], script: str = "dem", overrides: dict[str, str] | None = None,
           out_dir: str | None = None) -> list[TaskResult]:
    """The same tasks in a plain loop in this process: the benchmark's reference."""
    return [run_one(str(p), script, overrides, out_dir) for p in inputs]


# ------------------------------------------------------------------------------ the batch

Progress = Callable[[int, int, str], None]


class SchedulerError(Exception):
    """The Dask scheduler named on the command line cannot be used: a malformed address or one
    nobody answers at. Its own type so the command line reports it in one line, not a traceback."""


def scheduler_address(text: str) -> str:
    """``text`` checked as a Dask scheduler address (``tcp://host:8786``, ``host:8786``,
    ``tls://...``), so a typo such as ``--scheduler local`` is refused before any job is looked
    at, in words, rather than deep inside Dask's connect as ``missing port number``."""
    from distributed.comm.addressing import parse_address, parse_host_port
    from distributed.comm.registry import backends

    try:
        scheme, location = parse_address(text, strict=False)
        if scheme not in backends:
            raise ValueError(f"unknown scheme {scheme}://, known: {', '.join(sorted(backends))}")
        if scheme in ("tcp", "tls", "ws", "wss"):
            host, port = parse_host_port(location)
            if not host:
                raise ValueError("no host")
            if not 0 < int(port) < 65536:
                raise ValueError(f"port {port} is out of range 1-65535")
    except (ValueError, TypeError) as exc:
        raise SchedulerError(f"{text!r} is no Dask scheduler address ({exc}); write tcp://HOST:PORT, "
                             "e.g. tcp://127.0.0.1:8786, or leave --scheduler out for a LocalCluster here") from None
    return text


def make_client(scheduler: str | None = None, workers: int = 2, processes: bool = True,
                threads_per_worker: int = 1) -> Any:
    """A Dask client: to the cluster at ``scheduler``, else to a new LocalCluster here (one
    thread per worker process: the steps hold the GIL between numpy calls, so processes are
    what makes them parallel; ``processes=False`` for quick tests). A scheduler that is
    malformed or does not answer raises :class:`SchedulerError`."""
    from distributed import Client, LocalCluster

    if scheduler:
        scheduler_address(scheduler)
        try:
            return Client(scheduler)
        except (OSError, ValueError) as exc:
            raise SchedulerError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    cluster = LocalCluster(n_workers=workers, threads_per_worker=threads_per_worker, processes=processes,
                           dashboard_address=None)
    return Client(cluster)


def close_client(client: Any) -> None:
    cluster = getattr(client, "cluster", None)
    client.close()
    if cluster is not None:
        cluster.close()


def run_batch(
    script: str,
    inputs: Sequence[Path | str],
    overrides: dict[str, str] | None = None,
    *,
    client: Any = None,
    scheduler: str | None = None,
    workers: int = 2,
    processes: bool = True,
    out_dir: str | None = None,
    force: bool = False,
    dry_run: bool = False,
    progress: Progress | None = None,
) -> list[TaskResult]:
    """One Dask task per input; results in input order. Inputs whose products are newer than
    they are skipped here, before any task is made (unless ``force``); failures come back as
    results with ``status == "failed"``. ``client``: an open Dask client to reuse (the caller
    closes it); else one is made for this batch and closed after it."""
    from distributed import as_completed

    results: dict[str, TaskResult] = {}
    todo: list[str] = []
    for p in map(str, inputs):
        if not force and not dry_run:
            try:
                if is_current(find_job(p), out_dir, (overrides or {}).get("name")):
                    results[p] = TaskResult(p, "skipped")
                    continue
            except ReprocessError as exc:
                results[p] = TaskResult(p, "failed", error=str(exc))
                continue
        todo.append(p)
    total = len(results) + len(todo)
    if progress is not None:
        progress(len(results), total, f"{len(results)} up to date" if results else "submitting")
    if todo:
        own = client is None
        client = client or make_client(scheduler, workers, processes)
        try:
            futures = client.map(run_one, todo, script=script, overrides=overrides, out_dir=out_dir,
                                 dry_run=dry_run, pure=False)
            index = {f.key: p for f, p in zip(futures, todo, strict=True)}
            for future in as_completed(futures):
                p = index[future.key]
                try:
                    res = future.result()
                except Exception as exc:  # noqa: BLE001 - a worker lost mid-task: that input failed
                    res = TaskResult(p, "failed", error=f"{type(exc).__name__}: {exc}")
                results[p] = res
                if progress is not None:
                    progress(len(results), total, f"{res.status} {Path(p).name}")
        finally:
            if own:
                close_client(client)
    return [results[str(p)] for p in inputs]


# ------------------------------------------------------------------------------ campaign mosaic

TILE = 256  # cells: a TIFF tile, and the height of the band of rows computed at once
MOSAIC_LAYERS: dict[str, tuple[Any, float | None]] = {"dem": (np.float32, math.nan),
                                                       "variance": (np.float32, math.nan),
                                                       "count": (np.int32, None)}


def _site_layers(dem_path: Path) -> Layers:
    """The layers the fuse reads (dem, variance, count) and the meta that says how to read the
    variance; the other companions are left on disk."""
    import yaml

    dem, g = read_geotiff(dem_path)
    layers = Layers(g)
    layers["dem"] = np.asarray(dem, np.float32)
    sidecar = dem_path.with_suffix(".yaml")
    if sidecar.is_file():
        meta = (yaml.safe_load(sidecar.read_text()) or {}).get("meta")
        if isinstance(meta, dict):
            layers.meta.update(meta)
    stem = dem_path.name[: -len("_dem.tif")] if dem_path.name.endswith("_dem.tif") else dem_path.stem
    for name in ("variance", "count"):
        p = dem_path.with_name(f"{stem}_{name}.tif")
        if p.is_file():
            layers[name] = read_geotiff(p)[0]
    return layers


def campaign_geometry(paths: Sequence[Path], cell: float | None = None) -> tuple[GridGeometry, list[GridGeometry]]:
    """The mosaic's grid (the union of the sites, at the finest cell) from the headers alone."""
    sites = [read_geotiff_geometry(p) for p in paths]
    return union_geometry(sites, cell), sites


def _window(g: GridGeometry, r0: int, c0: int, rows: int, cols: int) -> GridGeometry:
    """A window of ``g`` on its own lattice (the same cells, so a tile equals the in-memory crop)."""
    return GridGeometry(g.cell, g.xmin + c0 * g.cell, g.ymax - r0 * g.cell, cols, rows)


def _overlaps(a: GridGeometry, b: GridGeometry) -> bool:
    return a.xmin < b.xmax and b.xmin < a.xmax and a.ymin < b.ymax and b.ymin < a.ymax


def mosaic_tiles(paths: Sequence[Path], geometry: GridGeometry, sites: Sequence[GridGeometry], *,
                 tile: int = TILE, **fuse: Any) -> Iterator[tuple[int, int, dict[str, np.ndarray]]]:
    """(row, col, layers) of each tile, row by row: one band of tile rows at a time, reading
    only the sites that overlap the band (and letting them go after it)."""
    rows, cols = geometry.shape
    for r0 in range(0, rows, tile):
        band = _window(geometry, r0, 0, min(tile, rows - r0), cols)
        wanted = [k for k, s in enumerate(sites) if _overlaps(s, band)]
        loaded = {k: _site_layers(Path(paths[k])) for k in wanted}
        for c0 in range(0, cols, tile):
            win = _window(geometry, r0, c0, band.height, min(tile, cols - c0))
            here = [k for k in wanted if _overlaps(sites[k], win)]
            if here:
                fused = dem_mosaik([loaded[k] for k in here], rule="fuse", geometry=win, **fuse)
                out = {"dem": fused["dem"], "variance": fused["variance"], "count": fused["count"]}
            else:
                out = {"dem": np.full(win.shape, np.nan, np.float32), "variance": np.full(win.shape, np.nan, np.float32),
                       "count": np.zeros(win.shape, np.int32)}
            yield r0, c0, out
        del loaded


def _padded(a: np.ndarray, tile: int, fill: Any) -> np.ndarray:
    if a.shape == (tile, tile):
        return a
    out = np.full((tile, tile), fill, a.dtype)
    out[: a.shape[0], : a.shape[1]] = a
    return out


def mosaic_campaign(paths: Sequence[Path | str], out_prefix: Path | str, *, cell: float | None = None,
                    tile: int = TILE, progress: Progress | None = None, **fuse: Any) -> dict[str, Path]:
    """Fuse the site DEMs into ``<out_prefix>_{dem,variance,count}.tif`` (tiled GeoTIFFs, written
    tile by tile: the dem as the tiles are made, the other two spooled to raw files on disk and
    written after, so no layer is ever whole in memory), with a YAML sidecar on the DEM."""
    paths = [Path(p) for p in paths]
    if not paths:
        raise ValueError("mosaic-campaign needs at least one site DEM")
    geometry, sites = campaign_geometry(paths, cell)
    out_prefix = Path(out_prefix)
    out_prefix.parent.mkdir(parents=True, exist_ok=True)
    rows, cols = geometry.shape
    n_tiles = math.ceil(rows / tile) * math.ceil(cols / tile)
    spool = {name: tempfile.TemporaryFile(dir=out_prefix.parent) for name in ("variance", "count")}
    files = {name: out_prefix.with_name(f"{out_prefix.name}_{name}.tif") for name in MOSAIC_LAYERS}
    stats = {"defined_cells": 0}

    def dem_tiles() -> Iterator[np.ndarray]:
        for i, (_, _, layers) in enumerate(mosaic_tiles(paths, geometry, sites, tile=tile, **fuse)):
            stats["defined_cells"] += int(np.isfinite(layers["dem"]).sum())
            for name, fh in spool.items():
                dtype, nodata = MOSAIC_LAYERS[name]
                fh.write(_padded(layers[name].astype(dtype), tile, 0 if nodata is None else nodata).tobytes())
            if progress is not None:
                progress(i + 1, n_tiles, f"tile {i + 1}/{n_tiles}")
            yield _padded(layers["dem"], tile, np.nan)

    def spooled(name: str) -> Iterator[np.ndarray]:
        dtype = np.dtype(MOSAIC_LAYERS[name][0])
        fh = spool[name]
        fh.seek(0)
        for _ in range(n_tiles):
            yield np.frombuffer(fh.read(tile * tile * dtype.itemsize), dtype).reshape(tile, tile)

    try:
        _write_tiled(files["dem"], dem_tiles(), geometry, np.float32, math.nan, tile)
        for name in ("variance", "count"):
            dtype, nodata = MOSAIC_LAYERS[name]
            _write_tiled(files[name], spooled(name), geometry, dtype, nodata, tile)
    finally:
        for fh in spool.values():
            fh.close()
    write_yaml_atomic(files["dem"].with_suffix(".yaml"), {
        "product": files["dem"].name, "made_by": "rvs-prox mosaic-campaign",
        "inputs": [str(p) for p in paths], "parameters": {"rule": "fuse", "cell": geometry.cell, "tile": tile, **fuse},
        "layer": "dem", "cell": geometry.cell, "bounds": list(geometry.bounds), "size": [cols, rows],
        "layers": {k: p.name for k, p in files.items()},
        "meta": {"rule": "fuse", "variance": "estimate", "inputs": len(paths)},
        "defined_cells": stats["defined_cells"],
    })
    return files


def _write_tiled(path: Path, tiles: Iterator[np.ndarray], geometry: GridGeometry, dtype: Any,
                 nodata: float | None, tile: int) -> None:
    """A tiled GeoTIFF from an iterator of tiles in row-major order (tifffile writes each tile as
    it comes), atomically."""
    with atomic_path(path) as tmp:
        tifffile.imwrite(tmp, tiles, shape=geometry.shape, dtype=dtype, tile=(tile, tile),
                         photometric="minisblack", compression="zlib", extratags=geo_tags(geometry, nodata))


def mosaic_in_memory(paths: Sequence[Path | str], cell: float | None = None, **fuse: Any) -> Layers:
    """The same mosaic made whole in memory: the reference the tiles are tested against."""
    layers = [_site_layers(Path(p)) for p in paths]
    geometry = union_geometry([site.geometry for site in layers], cell)
    return dem_mosaik(layers, rule="fuse", geometry=geometry, **fuse)
