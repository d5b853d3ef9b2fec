"""Benchmark of campaign reprocessing on Dask, side by side in one run:

1. N recorded scans reprocessed serially (a plain loop of the same task function in this
   process) and on a LocalCluster of 2 worker processes: wall time, speedup, and the per-task
   overhead of the cluster (its wall time x workers / N minus the serial time per task).
   The scans: ``--real`` small dem-full-tof scans through an in-process simulated server, the
   rest copies of them shifted by whole metres (coordinate images, .cal poses, scan.yaml and the
   DEM's sidecar moved together), so the campaign spreads over ground and the mosaic has size.
2. The task graph for 10,000 scans built (``client.map``) and scheduled to completion with the
   steps not run (``dry_run``): time, and per task.
3. The campaign mosaic (fuse over the N reprocessed site DEMs, tile by tile): its peak Python
   heap (tracemalloc: numpy's buffers are counted) vs the size of the mosaic on disk and
   uncompressed.

    python -m tools.bench.batch [--scans 40] [--real 2] [--workers 2] [--keep DIR]
"""

from __future__ import annotations

import argparse
import logging
import os
import socket
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np
import tifffile

from prox_workflows.batch import close_client, make_client, mosaic_campaign, run_batch, run_one, serial
from rvs_truth.synthetic import shifted_copy

SCAN = "dem-full-tof -range -20,20,-50,-30 -cell 0.05 -mesh false -name {name}"


def record_scans(data: Path, count: int) -> list[Path]:
    """``count`` real scans through an in-process simulated server (at poses 1.5 m apart)."""
    from tools.bench.server import start_rvs

    port, _ = start_rvs(data, ["server.scene=office", "server.warm_up=false"])
    sock = socket.create_connection(("127.0.0.1", port))
    reader = sock.makefile("rb")
    reader.readline()
    out = []
    def final(module: str) -> str:  # the request's final line (events and progress lines skipped)
        while True:
            line = reader.readline().decode()
            if line.startswith((f"{module} OK", f"{module} ERROR")):
                return line

    for i in range(count):
        sock.sendall(f"pose -x {1.5 * i} -y 0 -heading 0\n".encode())
        final("EGP-RVS-POSE")
        sock.sendall((SCAN.format(name=f"real{i}") + "\n").encode())
        line = final("EGP-RVS-DEM-FULL-TOF")
        if " ERROR " in line:
            raise RuntimeError(line)
        out.append(data / "dem" / f"real{i}_views")
    sock.close()
    return out


def make_campaign(root: Path, scans: int, real: int) -> list[Path]:
    """``root/site<k>/dem/site<k>_views``: ``real`` recorded scans, the rest shifted copies on a
    grid of sites 3 m apart."""
    recorded = record_scans(root / "_server", max(1, min(real, scans)))
    side = int(np.ceil(np.sqrt(scans)))
    out = []
    for k in range(scans):
        src = recorded[k % len(recorded)]
        dx, dy = 3.0 * (k % side), 3.0 * (k // side)
        out.append(shifted_copy(src, root / f"site{k:03d}" / "dem", f"site{k:03d}", dx, dy))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scans", type=int, default=40)
    ap.add_argument("--real", type=int, default=2, help="scans recorded through the server; the rest are copies")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--graph", type=int, default=10_000, help="inputs of the scheduling-only graph")
    ap.add_argument("--mosaic-cell", type=float, default=0.01,
                    help="the mosaic's cell (finer than the sites' 0.05 m: a mosaic with some size)")
    ap.add_argument("--keep", help="build the campaign here and keep it")
    args = ap.parse_args(argv)
    logging.getLogger("distributed").setLevel(logging.CRITICAL)  # a closing cluster's heartbeat noise
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at the start "
          "(other processes share the cores: the speedup is bounded by what is free)")
    tmp = None if args.keep else tempfile.TemporaryDirectory()
    root = Path(args.keep or tmp.name)  # type: ignore[union-attr]
    try:
        t0 = time.perf_counter()
        inputs = make_campaign(root, args.scans, args.real)
        print(f"campaign: {len(inputs)} scans ({min(args.real, args.scans)} recorded through the server, "
              f"the rest shifted copies) in {time.perf_counter() - t0:.1f} s")

        print(f"1. reprocessing {len(inputs)} scans (dem, cell 0.05 m)")
        serial(inputs[:1], out_dir=str(root / "_warm"))  # numba's kernels loaded once, outside the timing
        t0 = time.perf_counter()
        res_s = serial(inputs, out_dir=str(root / "_serial"))
        t_serial = time.perf_counter() - t0
        assert all(r.status == "done" for r in res_s), [r.error for r in res_s if r.error][:3]
        t0 = time.perf_counter()
        client = make_client(workers=args.workers)
        t_start = time.perf_counter() - t0
        try:
            run_batch("dem", inputs[:args.workers], client=client, out_dir=str(root / "_warm"), force=True)  # warm workers
            t0 = time.perf_counter()
            res_c = run_batch("dem", inputs, client=client)
            t_cluster = time.perf_counter() - t0
            assert all(r.status == "done" for r in res_c), [r.error for r in res_c if r.error][:3]
            t0 = time.perf_counter()
            again = run_batch("dem", inputs, client=client)
            t_skip = time.perf_counter() - t0
            assert all(r.status == "skipped" for r in again)

            n = len(inputs)
            task_s = np.median([r.seconds for r in res_s])
            print(f"   serial loop:                  {t_serial:7.2f} s  ({t_serial / n * 1e3:6.1f} ms per scan, "
                  f"task median {task_s * 1e3:.1f} ms)")
            print(f"   LocalCluster {args.workers} processes:     {t_cluster:7.2f} s  ({t_cluster / n * 1e3:6.1f} ms per scan)"
                  f"  speedup {t_serial / t_cluster:.2f}x (ideal {args.workers}x); cluster start {t_start:.1f} s (not counted)")
            overhead = t_cluster * args.workers / n - t_serial / n
            print(f"   per-task overhead vs the loop: {overhead * 1e3:+.1f} ms "
                  f"(cluster wall x workers / N - serial / N)")
            task_c = np.median([r.seconds for r in res_c])
            print(f"   one task's own time: median {task_c * 1e3:.1f} ms in a worker vs {task_s * 1e3:.1f} ms in the "
                  f"loop ({task_c / task_s:.2f}x: above 1, the workers waited for a core)")
            print(f"   re-run, all up to date:       {t_skip:7.2f} s ({n} skipped, no task made)")

            print(f"2. task graph of {args.graph:,} scans, steps not run (dry_run)")
            fake = [f"/campaign/site{k:05d}/dem/site{k:05d}_views" for k in range(args.graph)]
            t0 = time.perf_counter()
            futures = client.map(run_one, fake, dry_run=True, pure=False)
            t_build = time.perf_counter() - t0
            client.gather(futures)
            t_all = time.perf_counter() - t0
            print(f"   built (client.map) {t_build:6.2f} s; built + scheduled + run to completion {t_all:6.2f} s "
                  f"({t_all / args.graph * 1e3:.2f} ms per task)")
            del futures
        finally:
            close_client(client)

        print(f"   load average after: {os.getloadavg()[0]:.1f}")
        print(f"3. campaign mosaic (fuse over the sites at {args.mosaic_cell} m, tiles of 256 x 256 cells)")
        dems = [p.parent / "reprocessed" / f"{p.name[:-len('_views')]}_dem.tif" for p in inputs]
        tracemalloc.start()
        t0 = time.perf_counter()
        files = mosaic_campaign(dems, root / "mosaic" / "campaign", cell=args.mosaic_cell)
        t_mosaic = time.perf_counter() - t0
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        shape = tifffile.TiffFile(files["dem"]).pages[0].shape
        on_disk = sum(p.stat().st_size for p in files.values())
        raw = shape[0] * shape[1] * 12  # dem, variance float32 + count int32
        print(f"   {shape[1]} x {shape[0]} cells from {len(dems)} sites in {t_mosaic:.2f} s; peak heap "
              f"{peak / 1e6:.1f} MB vs {on_disk / 1e6:.1f} MB on disk (zlib), {raw / 1e6:.1f} MB uncompressed "
              f"(peak / uncompressed {peak / raw:.2f})")
    finally:
        if tmp is not None:
            tmp.cleanup()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
