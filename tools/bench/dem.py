"""Benchmark of the ToF DEM chain, side by side in one run:

1. DemImport of 1 M and 10 M points into a 0.02 m grid over 10 x 10 m (500 x 500 cells), against
   ``scipy.stats.binned_statistic_2d(statistic='max')`` on the same cells (the peer; it computes
   only the max, DemImport all of max, min, mean, count and variance - and, like for like, the
   max alone with ``stats=("dem",)``) and against one numpy pass
   over the same points (the floor): the flat cell index ``((x - xmin) / cell).astype(int32) +
   ((ymax - y) / cell).astype(int32) * width`` over the whole N x 3 array, the least any binning
   has to do. Targets: >= 20x the peer, <= 3x the floor, for the five layers and for all eight
   (N x 4 points with intensity and per-point variances: also measurement_variance, wmean and
   intensity; its floor is the same pass over that N x 4 array).
   DemImport is numba's one pass over the points; with >= 400 000 points, two a cell, and a core
   idle by the load average, two threads each scatter into half of the cells. Its JIT compile
   time (once per installation, then cached) and cache-load time are measured in fresh processes
   and reported apart, outside the timings. The compiled pass on one thread and on two (forced,
   whatever the load), and the numpy implementation (the fallback without numba), are timed too.
   The peer is timed best of 3 (it is slow); everything else best of --runs.
   The points are a synthetic 24-view ToF scan (each view a raster of pixels, in pixel order, on
   a rolling terrain around the rover - what DemImport gets from AcquireTofCoordImages); the
   same points shuffled are timed too (no spatial order: the worst case for the caches).
   At 10 M points the peer runs on a 1 M subset and its points/s are extrapolated (it sorts, so
   it would be slower per point at 10 M: the extrapolation flatters the peer). The peer's max and
   DemImport's dem differ only in cells with a point within 1e-4 cell of an edge, which
   np.digitize's float64 edges and GridGeometry.cell_of's arithmetic round differently.
2. Real data (``--realdata``, default on when ../shared/realdata is present): the Autzen airborne
   lidar's ground class (LAS, feet converted to metres) through DemImport against the peer on
   the same cells, at 1, 2 and 5 m; and a georeferenced copy of it (shifted to UTM-sized
   coordinates, 556440 E, 5394932 N) against the same points at the origin: the largest height
   difference, in float64 (this toolbox) and as it was with float32 coordinates.
3. Dem2Hazard of a 1000 x 1000 DEM: the section tools/bench/dem2hazard.py provides.
4. A 24-view dem-full-tof in simulation: the lead's section.
5. Hole filling on the HiRISE crop (with the real data): holes of 1-3 cells radius cut out, filled by
   prox_workflows/algorithms/holes.py and by GDAL's fillnodata (rasterio.fill), RMSE and max error
   against the cut-out heights, and the time of each.

Times are the minimum over interleaved repetitions (the machine may be shared); the spread
(median / minimum) of the main rows is printed beside them.

    python -m tools.bench.dem [--sizes 1000000,10000000] [--runs 5] [--skip-hazard] [--skip-dem-full-tof]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy import stats

import prox_workflows.algorithms.dem_import as dem_import_module
from prox_workflows.algorithms.dem_import import dem_import
from prox_workflows.grid import GridGeometry
from rvs_truth.synthetic import SIDE, tof_scan

CELL = 0.02
PEER_MAX_POINTS = 1_000_000


def floor_pass(points: np.ndarray, g: GridGeometry) -> np.ndarray:
    return ((points[:, 0] - g.xmin) / g.cell).astype(np.int32) + ((g.ymax - points[:, 1]) / g.cell).astype(np.int32) * g.width


def peer(points: np.ndarray, g: GridGeometry) -> np.ndarray:
    res = stats.binned_statistic_2d(points[:, 0], points[:, 1], points[:, 2], statistic="max",
                                    bins=[g.width, g.height], range=[[g.xmin, g.xmax], [g.ymin, g.ymax]])
    return res.statistic.T[::-1]  # x-major, y up -> north-up rows


def best_of(fns: dict[str, Callable[[], object]], runs: int) -> tuple[dict[str, float], dict[str, float]]:
    """Minimum and median time of each function over ``runs`` interleaved repetitions."""
    times: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(runs):
        for name, fn in fns.items():  # interleaved, so load changes hit all alike
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {k: min(v) for k, v in times.items()}, {k: statistics.median(v) for k, v in times.items()}


def with_impl(impl: str, threads: int | None = None) -> Callable[..., object]:
    """dem_import run by ``impl`` ("numba" or "numpy"); ``threads`` 1 or 2 forces that many
    (2: whatever the load average says), None leaves the module's choice."""
    def call(*args: object, **kwargs: object) -> object:
        saved = dem_import_module.IMPL, dem_import_module.THREADS, dem_import_module._core_free
        dem_import_module.IMPL = impl
        if threads is not None:
            dem_import_module.THREADS = threads
            dem_import_module._core_free = lambda: True  # type: ignore[assignment]
        try:
            return dem_import(*args, **kwargs)  # type: ignore[arg-type]
        finally:
            dem_import_module.IMPL, dem_import_module.THREADS, dem_import_module._core_free = saved
    return call


def compile_times() -> tuple[float, float, float] | None:
    """(import numba, JIT compile of every kernel variant, load of them from numba's cache) in
    seconds, each in a fresh process with an empty cache directory, then the same one again."""
    if not dem_import_module.HAVE_NUMBA:
        return None
    code = ("import time; t0 = time.perf_counter(); import numba; t1 = time.perf_counter(); "
            "from prox_workflows.algorithms import dem_import as m; m.warm_up(); "
            "print(t1 - t0, time.perf_counter() - t1)")
    root = Path(__file__).resolve().parents[2]
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]))
        out = [subprocess.run([sys.executable, "-c", code], env=env, cwd=root, capture_output=True, text=True,
                              check=True).stdout.split() for _ in range(2)]
    return float(out[0][0]), float(out[0][1]), float(out[1][1])


def section_dem_import(sizes: list[int], runs: int) -> bool:
    g = GridGeometry(CELL, 0.0, SIDE, int(round(SIDE / CELL)), int(round(SIDE / CELL)))
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"1. DemImport into {g.width} x {g.height} cells of {CELL} m over {SIDE:g} x {SIDE:g} m "
          f"(cpus {os.cpu_count()}, load average {load:.2f})")
    print("   layers: max (dem), min, mean, count, variance; floor = one numpy pass (flat cell index)")
    numba_ok = dem_import_module.HAVE_NUMBA
    ct = compile_times()
    if ct is None:
        print("   numba is not installed: DemImport runs its numpy implementation")
    else:
        import numba

        t0 = time.perf_counter()
        dem_import_module.warm_up()  # this installation's cache: out of the timings below
        print(f"   numba {numba.__version__}: import numba {ct[0]:.2f} s; JIT compile of the kernels {ct[1]:.2f} s "
              f"(first run per installation); load from numba's cache {ct[2]:.2f} s (each later process; "
              f"here {time.perf_counter() - t0:.2f} s) - all outside the timings")
    ok = True
    numpy_impl, one_thread, two_threads = with_impl("numpy"), with_impl("numba", 1), with_impl("numba", 2)
    for n in sizes:
        pts = tof_scan(n)
        shuffled = pts[np.random.default_rng(1).permutation(len(pts))]
        rng = np.random.default_rng(3)
        pts4 = np.column_stack([pts, rng.uniform(100, 900, len(pts)).astype(np.float32)])
        var = rng.uniform(1e-6, 1e-4, len(pts))
        dem_import(pts[:100_000], geometry=g)  # warm-up (allocator, caches)
        peer(pts[:10_000], g)
        fns: dict[str, Callable[[], object]] = {
            "floor": lambda p=pts: floor_pass(p, g),
            "ours": lambda p=pts: dem_import(p, geometry=g),
            "floor4": lambda p=pts4: floor_pass(p, g),
            "ours_all": lambda p=pts4, v=var: dem_import(p, geometry=g, point_variance=v),
            "ours_random": lambda p=shuffled: dem_import(p, geometry=g),
            "ours_max": lambda p=pts: dem_import(p, geometry=g, stats=("dem",)),
            "numpy": lambda p=pts: numpy_impl(p, geometry=g),
            "numpy_all": lambda p=pts4, v=var: numpy_impl(p, geometry=g, point_variance=v),
        }
        if numba_ok:
            fns["one_thread"] = lambda p=pts: one_thread(p, geometry=g)
            fns["two_threads"] = lambda p=pts: two_threads(p, geometry=g)
            fns["one_thread_all"] = lambda p=pts4, v=var: one_thread(p, geometry=g, point_variance=v)
            fns["two_threads_all"] = lambda p=pts4, v=var: two_threads(p, geometry=g, point_variance=v)
        free = numba_ok and dem_import_module._core_free()
        t, med = best_of(fns, runs)
        sub = pts if len(pts) <= PEER_MAX_POINTS else pts[np.random.default_rng(2).choice(len(pts), PEER_MAX_POINTS, replace=False)]
        t_peer = float("inf")
        for _ in range(3):
            t0 = time.perf_counter()
            peer_max = peer(sub, g)
            t_peer = min(t_peer, time.perf_counter() - t0)
        ours_sub = dem_import(sub, geometry=g)["dem"]
        agree = np.mean(np.where(np.isnan(peer_max), np.isnan(ours_sub), peer_max == ours_sub))
        n_pts = len(pts)
        pps = {k: n_pts / v for k, v in t.items()}
        peer_pps = len(sub) / t_peer
        r_floor = t["ours"] / t["floor"]
        r_peer = pps["ours"] / peer_pps
        r_floor_all = t["ours_all"] / t["floor4"]
        r_peer_all = pps["ours_all"] / peer_pps
        extrap = "" if len(sub) == n_pts else f" (on a {len(sub) / 1e6:.0f} M subset, points/s extrapolated)"

        def row(label: str, key: str, floor: str = "floor", note: str = "", t=t, med=med, pps=pps,
                peer_pps=peer_pps) -> None:
            print(f"     {label:<38}{t[key] * 1e3:8.1f} ms  {pps[key] / 1e6:8.1f} M points/s"
                  f"   {t[key] / t[floor]:4.2f}x the floor   {pps[key] / peer_pps:5.1f}x the peer{note}"
                  f"   (median {med[key] * 1e3:.1f} ms)")

        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
        print(f"   {n_pts / 1e6:5.1f} M points (scan order); load average {load:.2f}: DemImport "
              f"{'may use two threads' if free else 'runs on one thread (no idle core)'}")
        print(f"     {'floor, one numpy pass (N x 3)':<38}{t['floor'] * 1e3:8.1f} ms  {pps['floor'] / 1e6:8.1f} M points/s"
              f"   (median {med['floor'] * 1e3:.1f} ms)")
        row("DemImport, 5 layers", "ours", note="   targets <= 3x floor, >= 20x peer")
        print(f"     {'floor, one numpy pass (N x 4)':<38}{t['floor4'] * 1e3:8.1f} ms  {pps['floor4'] / 1e6:8.1f} M points/s"
              f"   (median {med['floor4'] * 1e3:.1f} ms)")
        row("DemImport, all 8 layers (N x 4, var)", "ours_all", "floor4", note="   targets <= 3x floor, >= 20x peer")
        row("DemImport, 5 layers, shuffled points", "ours_random")
        row("DemImport, dem (max) only", "ours_max", note=" (same statistic)")
        if numba_ok:
            row("DemImport, 5 layers, one thread", "one_thread")
            row("DemImport, 5 layers, two threads", "two_threads")
            row("DemImport, 8 layers, one thread", "one_thread_all", "floor4")
            row("DemImport, 8 layers, two threads", "two_threads_all", "floor4")
        row("numpy implementation, 5 layers", "numpy")
        row("numpy implementation, all 8 layers", "numpy_all", "floor4")
        print(f"     {'peer binned_statistic_2d':<38}{t_peer * 1e3:8.1f} ms  {peer_pps / 1e6:8.1f} M points/s{extrap}")
        print(f"     peer's max equals DemImport's dem on {100 * agree:.3f} % of the cells")
        met = r_peer >= 20 and r_floor <= 3 and r_peer_all >= 20 and r_floor_all <= 3
        print(f"     targets {'met' if met else 'NOT met'}: 5 layers {r_floor:.2f}x the floor, {r_peer:.1f}x the peer; "
              f"all 8 layers {r_floor_all:.2f}x the floor, {r_peer_all:.1f}x the peer")
        ok &= met
    return ok


# ---------------------------------------------------------------------------------------------
# 2. Dem2Hazard of a 1000 x 1000 DEM - provided by tools/bench/dem2hazard.py (its author's section)
# ---------------------------------------------------------------------------------------------
def section_dem2hazard() -> None:
    print("2. Dem2Hazard of a 1000 x 1000 DEM (tools/bench/dem2hazard.py)")
    try:
        from tools.bench import dem2hazard
    except ImportError as exc:  # pragma: no cover - until that part lands
        print(f"   not available: {exc}")
        return
    dem2hazard.main(["--runs", "5"])


# ---------------------------------------------------------------------------------------------
# 3. 24-view dem-full-tof in simulation, PTU motion time zero, target <= 3 s end to end
# ---------------------------------------------------------------------------------------------
def section_dem_full_tof(runs: int = 2) -> None:
    """Through a real server and socket: request to final OK, and where the time goes; once with
    the simulator's full ToF physics, once with a cheap one (no supersampling, no multipath) to
    show the pipeline's own share."""
    for label, overrides in (("full sim physics", []),
                             ("cheap sim (sim_supersample=1, sim_multipath_gain=0)",
                              ["drivers.tof.sim_supersample=1", "drivers.tof.sim_multipath_gain=0"])):
        _dem_full_tof_runs(runs, label, overrides)


def _dem_full_tof_runs(runs: int, label: str, overrides: list[str]) -> None:
    import socket
    import tempfile
    import time
    from pathlib import Path

    import yaml

    from tools.bench.server import start_rvs

    print(f"3. 24-view dem-full-tof in simulation (office, PTU motion time zero, {label})")
    with tempfile.TemporaryDirectory() as tmp:
        port, _ = start_rvs(Path(tmp), overrides)
        sock = socket.create_connection(("127.0.0.1", port))
        reader = sock.makefile("rb")
        reader.readline()
        for i in range(runs):
            t0 = time.perf_counter()
            sock.sendall(f"dem-full-tof -range -180,180,-50,-10 -overlap 0.3 -name bench{i}\n".encode())
            while True:
                line = reader.readline().decode()
                if line.startswith("EGP-RVS-DEM-FULL-TOF OK") or line.startswith("EGP-RVS-DEM-FULL-TOF ERROR"):
                    break
            total = time.perf_counter() - t0
            log = yaml.safe_load((Path(tmp) / "dem" / f"bench{i}_dem.yaml").read_text())["run_log"]["steps"]
            steps = {e["step"]: e["seconds"] for e in log}
            views = line.split("views=")[1].split()[0] if "views=" in line else "?"
            processing = sum(v for k, v in steps.items() if k != "acquire")
            print(f"   run {i + 1}: {views} views, {total:.2f} s end to end (target <= 3 s): "
                  f"acquisition {steps.get('acquire', 0):.2f} s, processing {processing:.2f} s, "
                  f"writing products {max(total - sum(steps.values()), 0):.2f} s")
        sock.close()


REALDATA = Path(__file__).resolve().parents[2].parent / "shared" / "realdata"
UTM_SHIFT = np.array([556440.0, 5394932.0])


def section_realdata() -> None:
    """The Autzen ground class against binned_statistic_2d, and origin vs UTM coordinates."""
    from prox_workflows.pointcloud import read_las

    las = REALDATA / "points" / "autzen_trim.las"
    if not las.is_file():
        print(f"\nreal data: {las} absent, section skipped")
        return
    t0 = time.perf_counter()
    ground, info = read_las(las, [2])
    t_read = time.perf_counter() - t0
    print(f"\nreal data: {las.name}, ground class {len(ground)} of {sum(info.classes.values())} points "
          f"(read {t_read * 1e3:.0f} ms, unit {info.unit_m} m)")
    print(f"  {'cell':>6} {'cells':>9} {'defined':>8} {'DemImport max':>14} {'peer':>10} {'max |diff|':>11}")
    for cell in (1.0, 2.0, 5.0):
        g = GridGeometry.covering(*ground[:, :2].min(axis=0), *ground[:, :2].max(axis=0), cell)
        times, _ = best_of({"ours": lambda g=g: dem_import(ground, g, stats=("dem",)),
                            "peer": lambda g=g: peer(ground, g)}, 3)
        ours, ref = dem_import(ground, g, stats=("dem",))["dem"], peer(ground, g)
        both = np.isfinite(ours) & np.isfinite(ref)
        print(f"  {cell:>5g}m {ours.size:>9} {int(np.isfinite(ours).sum()):>8} {times['ours'] * 1e3:>11.2f} ms "
              f"{times['peer'] * 1e3:>7.1f} ms {float(np.max(np.abs(ours[both] - ref[both]))):>11.2e}")
    local = ground[:, :3] - np.r_[ground[:, :2].min(axis=0), 0.0]
    utm = local.copy()
    utm[:, :2] += UTM_SHIFT
    for label, dtype in (("float64", np.float64), ("float32 (before)", np.float32)):
        ga = GridGeometry(1.0, 0.0, 180.0, 360, 180)
        gb = GridGeometry(1.0, UTM_SHIFT[0], UTM_SHIFT[1] + 180.0, 360, 180)
        a = dem_import(local.astype(dtype), ga, stats=("dem",))["dem"]
        b = dem_import(utm.astype(dtype), gb, stats=("dem",))["dem"]
        both = np.isfinite(a) & np.isfinite(b)
        print(f"  origin vs UTM, {label:<17} defined {int(np.isfinite(a).sum())} vs {int(np.isfinite(b).sum())}, "
              f"max |diff| {float(np.max(np.abs(a[both] - b[both]))):.3g} m")


HOLE_RADII = (1, 2, 3)  # cells: the radii of the holes cut out of the HiRISE crop
HOLES = 40


def cut_holes(z: np.ndarray, seed: int = 0) -> np.ndarray:
    """Mask of ``HOLES`` disks of 1-3 cells radius at random places inside ``z`` (not touching its
    border, so every hole has ground all round, as a gap in a DEM has), without overlaps."""
    rng = np.random.default_rng(seed)
    mask = np.zeros(z.shape, bool)
    rr, cc = np.mgrid[0:z.shape[0], 0:z.shape[1]]
    placed = 0
    while placed < HOLES:
        rad = int(rng.choice(HOLE_RADII))
        r, c = (int(rng.integers(rad + 2, n - rad - 2)) for n in z.shape)
        disk = (rr - r) ** 2 + (cc - c) ** 2 <= rad * rad
        if (mask & (np.hypot(rr - r, cc - c) <= rad + 2)).any():
            continue
        mask |= disk
        placed += 1
    return mask


def section_holes(runs: int = 5) -> None:
    """Hole filling on the HiRISE crop with cut-out holes: our fill (prox_workflows/algorithms/holes.py,
    first-order normalised convolution) against GDAL's (rasterio.fill.fillnodata: inverse distance
    weighting along search rays, no smoothing), on the same holes, against the cut-out truth."""
    from prox_workflows.algorithms.holes import fill_holes_array

    dtm = REALDATA / "dem" / "mars_dtm.npy"
    if not dtm.is_file():
        print(f"\nhole filling: {dtm} absent, section skipped")
        return
    try:
        from rasterio.fill import fillnodata
    except ImportError:  # pragma: no cover - rasterio is a test dependency
        fillnodata = None
    truth = np.load(dtm).astype(np.float32)
    holes = cut_holes(truth)
    dem = np.where(holes, np.nan, truth).astype(np.float32)
    radius = float(max(HOLE_RADII)) + 0.5
    fills: dict[str, Callable[[], np.ndarray]] = {
        "ours (holes.py, plane by normalised convolution)": lambda: fill_holes_array(dem, radius)[0],
    }
    if fillnodata is not None:
        def gdal() -> np.ndarray:
            return fillnodata(np.where(holes, 0.0, truth).astype(np.float32), mask=(~holes).astype(np.uint8),
                              max_search_distance=10.0, smoothing_iterations=0)
        fills["GDAL (rasterio.fill.fillnodata, IDW)"] = gdal
    t, _ = best_of(fills, runs)
    print(f"\nhole filling: HiRISE crop {truth.shape[1]} x {truth.shape[0]} cells of 1.01 m, {HOLES} holes of "
          f"radius {', '.join(map(str, HOLE_RADII))} cells cut out ({int(holes.sum())} cells), error vs the cut-out "
          f"heights (slopes median 21 deg)")
    print(f"  {'method':<50} {'filled':>7} {'RMSE':>8} {'max |err|':>10} {'time':>9}")
    for name, fn in fills.items():
        out = np.asarray(fn(), np.float64)
        got = holes & np.isfinite(out)
        err = out[got] - truth[got]
        print(f"  {name:<50} {int(got.sum()):>7} {float(np.sqrt(np.mean(err**2))):>6.3f} m "
              f"{float(np.max(np.abs(err))):>8.3f} m {t[name] * 1e3:>6.2f} ms")
    if fillnodata is None:
        print("  GDAL row: rasterio is not installed (pip install rasterio)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000000,10000000", help="point counts (default 1000000,10000000)")
    ap.add_argument("--runs", type=int, default=5, help="interleaved timed runs, the minimum counts (default 5)")
    ap.add_argument("--skip-hazard", action="store_true", help="leave out the Dem2Hazard section")
    ap.add_argument("--skip-realdata", action="store_true", help="leave out the real-data section")
    ap.add_argument("--skip-dem-full-tof", action="store_true", help="leave out the dem-full-tof section (it starts a server)")
    args = ap.parse_args(argv)
    sizes = [int(float(s)) for s in args.sizes.split(",") if s]
    ok = section_dem_import(sizes, args.runs)
    if not args.skip_realdata:
        section_realdata()
        section_holes()
    if not args.skip_hazard:
        section_dem2hazard()
    if not args.skip_dem_full_tof:
        section_dem_full_tof()
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
