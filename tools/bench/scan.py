"""A dem-full-tof scan against what the hardware allows, side by side in one server.

For each scene and view range, the same request through a real socket, the PTU back at pan 0,
tilt 0 before each run, the simulated world in real time (``sim.time_scale=1``, the PTU on the
world's clock as ``rvs-server`` starts):

- before: the views in rows from the lowest pan and tilt, each processed after the PTU stopped
  at it and before it moves on (``dem_full_tof.order=rows``, ``overlap_processing=false``);
- old sim (``--old-sim``): the same on the emulator's earlier timing, axes ramping from rest
  (base speed 0, ``PB0``/``TB0``), which the D46 does not do at its default base speed of 1000
  positions/s: the README's earlier 35.8-43.6 s;
- now: the planned order (the serpentine the PTU travels soonest) with each view processed while
  the PTU moves on (the defaults);
- limit: the fewest views, the PTU's travel along the shortest serpentine at the unit's speed,
  acceleration and base speed (read from it), and the ToF's frames at each view
  (:func:`prox_workflows.algorithms.ptu_positions.scan_limit`); ratio = now / limit.

Cells: defined DEM cells; RMSE: against the world's true DEM on plain terrain cells (no objects,
3 cells' margin) within 4 m of the rover. The time depends on the PTU's speed setting
(drivers.ptu.speed), the ToF's integration time and frames a view (-integrate, the wrap check),
and the machine's load (the simulator renders each view's frames on the CPU: time the hardware
does not spend).

    python -m tools.bench.scan [--scenes office quarry marsyard] [--range=-180,180,-50,-10 ...]
                               [--old-sim] [--runs 1]
"""

from __future__ import annotations

import argparse
import os
import socket
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy import ndimage

from prox_workflows.algorithms.ptu_positions import scan_limit
from prox_workflows.grid import read_geotiff

RANGES = ("-180,180,-50,-10", "-90,90,-50,-15")
OVERLAP = 0.3
NEAR = 4.0  # m: the RMSE's radius around the rover (the ToF's trusted range is 4.5 m)


class Client:
    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port))
        self.reader = self.sock.makefile("rb")
        self.reader.readline()  # greeting

    def request(self, line: str, timeout: float = 600.0) -> str:
        """The request's final line (OK or ERROR), past its ACK, PROGRESS and any EVENT."""
        self.sock.settimeout(timeout)
        self.sock.sendall(f"{line}\n".encode())
        while True:
            reply = self.reader.readline().decode()
            if not reply:
                raise RuntimeError(f"the server closed the connection during {line!r}")
            tokens = reply.split()
            if len(tokens) > 1 and tokens[1] in ("OK", "ERROR"):
                return reply.strip()


def fields(reply: str) -> dict[str, str]:
    return dict(tok.split("=", 1) for tok in reply.split() if "=" in tok)


def accuracy(app: Any, path: Path) -> tuple[int, float]:
    """Defined cells, and RMSE against the truth on plain terrain within NEAR of the rover."""
    dem, g = read_geotiff(path)
    world = app.world
    truth = world.true_dem(g.cell, g.bounds)
    bare = world.true_dem(g.cell, g.bounds, include_objects=False)
    objects = ~np.isclose(bare, truth, atol=1e-6) | ~np.isfinite(truth)
    terrain = ~ndimage.binary_dilation(objects, iterations=3)
    xs, ys = g.centers()
    rx, ry, _ = world.rover_pose()
    near = np.hypot(xs[None, :] - rx, ys[:, None] - ry) <= NEAR
    ok = np.isfinite(dem) & terrain & near
    return int(np.isfinite(dem).sum()), float(np.sqrt(np.mean((dem[ok] - truth[ok]) ** 2)))


def run_scan(app: Any, client: Client, view_range: str, name: str, variant: str) -> dict[str, Any]:
    ptu = app.devices.get("ptu")
    legacy = variant != "now"
    client.request(f"config -module dem_full_tof -set order={'rows' if legacy else 'fastest'}")
    client.request(f"config -module dem_full_tof -set overlap_processing={'false' if legacy else 'true'}")
    base = 0 if variant == "old sim" else 1000
    ptu.raw(f"PB{base}")
    ptu.raw(f"TB{base}")
    reply = client.request("move-ptu -pan 0 -tilt 0")
    assert " OK" in reply, reply
    t0, c0 = time.perf_counter(), app.world.clock.now()
    reply = client.request(f"dem-full-tof -range {view_range} -overlap {OVERLAP} -name {name}")
    wall, sim = time.perf_counter() - t0, app.world.clock.now() - c0
    ptu.raw("PB1000")
    ptu.raw("TB1000")
    if " OK" not in reply:
        raise RuntimeError(f"{variant} scan failed: {reply}")
    f = fields(reply)
    cells, rmse = accuracy(app, app.data_dir / f["dem"])
    return {"wall": wall, "sim": sim, "views": int(f["views"]), "cells": cells, "rmse": rmse}


def limit_of(app: Any, view_range: str) -> dict[str, Any]:
    from rvs_server.commands.dem import DemTofConfig
    from rvs_server.scanning import view_seconds

    ptu, tof = app.devices.get("ptu"), app.devices.get("tof")
    lim = ptu.limits()
    limits = (lim["pan"]["min_deg"], lim["pan"]["max_deg"], lim["tilt"]["min_deg"], lim["tilt"]["max_deg"])
    K, _ = tof.intrinsics()
    fov = tuple(float(np.degrees(2 * np.arctan(n / 2 / K[i, i]))) for i, n in ((0, 176), (1, 144)))
    seconds, _ = view_seconds(tof, DemTofConfig())
    rng = [float(v) for v in view_range.split(",")]
    return scan_limit(rng, fov, OVERLAP, limits, ptu.motion(), (0.0, 0.0), seconds)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="+", default=["office", "quarry", "marsyard"])
    ap.add_argument("--range", action="append", dest="ranges", metavar="PAN_MIN,PAN_MAX,TILT_MIN,TILT_MAX",
                    help=f"a view range (repeat for more; give it as --range=-180,...; default {' and '.join(RANGES)})")
    ap.add_argument("--old-sim", action="store_true", help="also run the old order on the emulator's earlier timing")
    ap.add_argument("--runs", type=int, default=1, help="runs of each variant (the fastest is kept)")
    args = ap.parse_args(argv)
    args.ranges = args.ranges or list(RANGES)

    from tools.bench.server import start_rvs, wait_warm_up

    variants = ["before", *(["old sim"] if args.old_sim else []), "now"]
    rows = []
    for scene in args.scenes:
        with tempfile.TemporaryDirectory() as tmp:
            port, app = start_rvs(Path(tmp), [f"server.scene={scene}", "drivers.ptu.time_scale=null",
                                              "sim.time_scale=1"])
            wait_warm_up()
            client = Client(port)
            for r, view_range in enumerate(args.ranges):
                limit = limit_of(app, view_range)
                best: dict[str, dict[str, Any]] = {}
                for run in range(args.runs):
                    for variant in variants:  # interleaved: a load change hits every variant alike
                        res = run_scan(app, client, view_range, f"{scene}{r}{variant[0]}{run}", variant)
                        if variant not in best or res["wall"] < best[variant]["wall"]:
                            best[variant] = res
                        print(f"  {scene} {view_range} {variant}: {res['wall']:.2f} s wall, {res['sim']:.2f} s "
                              f"simulated, {res['views']} views, {res['cells']} cells, RMSE "
                              f"{res['rmse'] * 100:.2f} cm (load {os.getloadavg()[0]:.1f})", flush=True)
                rows.append((scene, view_range, limit, best))
            client.sock.close()
    print()
    old = " | old sim (s)" if args.old_sim else ""
    print(f"| scene | range | views | before (s){old} | now (s) | limit (s): travel + frames | now / limit "
          "| cells before / now | RMSE before / now (cm) |")
    print("|---|---|---|---|---|---|---|---|---|" + ("---|" if args.old_sim else ""))
    for scene, view_range, limit, best in rows:
        b, n = best["before"], best["now"]
        o = f" | {best['old sim']['wall']:.1f}" if args.old_sim else ""
        print(f"| {scene} | {view_range} | {n['views']} | {b['wall']:.1f}{o} | {n['wall']:.1f} | {limit['total']:.1f}: "
              f"{limit['travel']:.1f} + {limit['exposure']:.1f} | {n['wall'] / limit['total']:.2f} | "
              f"{b['cells']} / {n['cells']} | {b['rmse'] * 100:.2f} / {n['rmse'] * 100:.2f} |")
    print(f"\nload average at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
