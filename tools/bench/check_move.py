"""Benchmark: the check-move safety gate on a 1000 x 1000 traversability map (target < 50 ms),
as a function call and as a request through a real server, side by side with a brute-force
sweep (every map cell tested against every footprint pose: the obvious implementation).

    python -m tools.bench.check_move
"""

from __future__ import annotations

import math
import socket
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from prox_workflows.algorithms.safety import check_move, sweep_poses
from prox_workflows.grid import GridGeometry, Layers

MOVES = {"0.5 m forward": (0.5, 0.0, 0.0), "2 m diagonal": (1.5, 1.3, 0.0), "turn 90 deg": (0.0, 0.0, 90.0),
         "3 m with a 45 deg turn": (2.5, 1.5, 45.0)}


def brute_force(t: np.ndarray, g: GridGeometry, start: tuple, end: tuple, length: float, width: float) -> str:
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    covered = np.zeros(g.shape, bool)
    for x, y, h in sweep_poses(start, end, step=max(g.cell, min(length, width) / 4)):
        c, s = math.cos(math.radians(h)), math.sin(math.radians(h))
        u, v = (X - x) * c + (Y - y) * s, -(X - x) * s + (Y - y) * c
        covered |= (np.abs(u) <= length / 2 + g.cell / 2) & (np.abs(v) <= width / 2 + g.cell / 2)
    under = t[covered]
    return "not_traversable" if (under <= 0).any() else "unknown" if np.isnan(under).any() else "ok"


def best_of(fn, n: int = 7) -> float:
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    g = GridGeometry(0.02, -10.0, 10.0, 1000, 1000)
    rng = np.random.default_rng(0)
    t = rng.uniform(0.2, 1.0, g.shape).astype(np.float32)
    t[rng.random(g.shape) < 2e-4] = np.nan  # a few unseen cells
    t[rng.random(g.shape) < 2e-4] = 0.0  # and a few impassable ones
    print(f"{'move':<26}{'check_move ms':>14}{'brute force ms':>16}{'ratio':>8}  verdict")
    for name, (dx, dy, dyaw) in MOVES.items():
        end = (dx, dy, dyaw)
        fast = best_of(lambda end=end: check_move(t, g, (0.0, 0.0, 0.0), end, 0.71, 0.6))
        slow = best_of(lambda end=end: brute_force(t, g, (0.0, 0.0, 0.0), end, 0.71, 0.6), 2)
        verdict = check_move(t, g, (0.0, 0.0, 0.0), end, 0.71, 0.6).verdict
        assert verdict == brute_force(t, g, (0.0, 0.0, 0.0), end, 0.71, 0.6)
        print(f"{name:<26}{fast * 1000:>14.2f}{slow * 1000:>16.1f}{slow / fast:>8.0f}  {verdict}")

    # through the server: a request round trip with a 1000 x 1000 map loaded as the current DEM
    from tools.bench.server import start_rvs

    with tempfile.TemporaryDirectory() as tmp:
        port, app = start_rvs(Path(tmp))
        app.maps.replace(Layers(g, {"dem": np.zeros(g.shape, np.float32), "traversability": t}), "bench", {})
        sock = socket.create_connection(("127.0.0.1", port))
        reader = sock.makefile("rb")
        reader.readline()
        lat = []
        for _ in range(200):
            t0 = time.perf_counter()
            sock.sendall(b"check-move -dx 2 -dy 0.5 -dyaw 20\n")
            reader.readline()
            lat.append(time.perf_counter() - t0)
        sock.close()
        lat_ms = np.array(lat) * 1000
        print(f"check-move request through the server, 1000 x 1000 map: p50 {np.percentile(lat_ms, 50):.2f} ms, "
              f"p99 {np.percentile(lat_ms, 99):.2f} ms (target < 50 ms)")
        extremes(port, app)


EXTREMES = ("-dx 50 -dy 50", "-dx -50 -dy 50 -dyaw 360", "-dyaw 360", "-to 150,150", "-to 1e6,1e6")


def extremes(port: int, app: object) -> None:
    """The help's extremes, each sent ten times on one connection while another polls status as
    fast as it answers: the reply time, and status's latency meanwhile (target p99 < 20 ms: the
    sweep runs off the event loop). On the 2 cm and on a 5 cm map (the box's bound is in cells)."""
    for cell in (0.02, 0.05):
        g = GridGeometry(cell, -500 * cell, 500 * cell, 1000, 1000)
        t = np.full(g.shape, 0.8, np.float32)
        app.maps.replace(Layers(g, {"dem": np.zeros(g.shape, np.float32), "traversability": t}), "bench", {})
        print(f"\nextremes on a 1000 x 1000 map of {cell * 100:g} cm cells")
        print(f"{'check-move':<28}{'reply p50 ms':>13}{'reply max ms':>13}{'status n':>9}{'status p99 ms':>14}  reply")
        for args in EXTREMES:
            replies: list[float] = []
            polls: list[float] = []
            stop = threading.Event()

            def poll(stop: threading.Event = stop, polls: list[float] = polls) -> None:
                sock = socket.create_connection(("127.0.0.1", port))
                reader = sock.makefile("rb")
                reader.readline()
                while not stop.is_set():
                    t0 = time.perf_counter()
                    sock.sendall(b"status\n")
                    reader.readline()
                    polls.append(time.perf_counter() - t0)
                sock.close()

            poller = threading.Thread(target=poll)
            poller.start()
            sock = socket.create_connection(("127.0.0.1", port))
            reader = sock.makefile("rb")
            reader.readline()
            for _ in range(10):
                t0 = time.perf_counter()
                sock.sendall(f"check-move {args}\n".encode())
                line = reader.readline().decode().strip()
                replies.append(time.perf_counter() - t0)
            sock.close()
            stop.set()
            poller.join()
            r, p = np.array(replies) * 1000, np.array(polls) * 1000
            verdict = line.split(" ")[2] if " OK " in line else line.split("code=")[1].split(" ")[0]
            print(f"{args:<28}{np.percentile(r, 50):>13.1f}{r.max():>13.1f}{len(p):>9}"
                  f"{np.percentile(p, 99):>14.2f}  {verdict}")


if __name__ == "__main__":
    main()
