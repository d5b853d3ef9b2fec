"""The terrain walk: the compiled kernel gives the numpy walk's bits, and runs without the GIL.

A render thread in the server walks rays for seconds a grab; a walk that takes the GIL between
its steps holds the event loop's ``status`` up whenever the OS takes the core from that thread
while it holds it (the latency itself is measured by ``python -m tools.bench.server --kinds
grab-stereo``, not here)."""

from __future__ import annotations

import sys
import threading
import time

import numpy as np
import pytest

from drivers.sim import raycast
from drivers.sim.render import camera_rays
from drivers.sim.world import World

pytestmark = pytest.mark.skipif(not raycast.HAVE_NUMBA, reason="the compiled walk needs numba")


def _rays(scene: str, sensor: str, w: int, h: int) -> tuple[World, np.ndarray, np.ndarray]:
    world = World.from_scene(scene, seed=3)
    K = np.asarray(world.camera_intrinsics(sensor, w, h), np.float64)
    o, d = camera_rays(K, w, h, np.asarray(world.sensor_pose(sensor), np.float64))
    return world, o, d


@pytest.mark.parametrize(("scene", "sensor", "w", "h"), [("office", "tof", 176, 144), ("marsyard", "left", 320, 240),
                                                          ("quarry", "left", 320, 240)])
def test_the_kernel_walk_gives_the_numpy_walks_bits(monkeypatch, scene: str, sensor: str, w: int, h: int) -> None:
    world, o, d = _rays(scene, sensor, w, h)
    # an object's depth stops some rays early, as in a render
    limit = np.where(np.arange(d.shape[0]) % 7 == 0, 2.0, np.inf)
    out = {}
    for impl in ("numpy", "numba"):
        monkeypatch.setattr(raycast, "IMPL", impl)
        out[impl] = raycast.cast_heightfield(world.terrain, o, d, limit)
    hits = np.isfinite(out["numpy"])
    assert hits.sum() > 1000, "the view sees the terrain"
    assert np.array_equal(out["numpy"].view(np.int64), out["numba"].view(np.int64))


def test_the_walk_runs_while_another_thread_holds_the_gil() -> None:
    """This thread spins in pure Python with a switch interval so long that it never hands the
    GIL over: a walker that needs the GIL between its steps makes no progress meanwhile, one
    inside a nogil kernel goes on computing. The walker's CPU clock tells which."""
    world, o, d = _rays("quarry", "left", 1280, 960)
    raycast.warm_up()
    inside = threading.Event()
    real = raycast._walker()

    def walk(*args):
        inside.set()
        return real(*args)

    raycast._compiled[0] = walk
    walker = threading.Thread(target=raycast.cast_heightfield, args=(world.terrain, o, d, np.full(d.shape[0], np.inf)))
    old = sys.getswitchinterval()
    best = 0.0
    try:
        walker.start()
        assert inside.wait(60), "the walk did not start"
        clock = time.pthread_getcpuclockid(walker.ident or 0)
        sys.setswitchinterval(1000.0)
        for _ in range(20):  # a few tries: the loaded machine may not run the walker in one
            time.sleep(0.05)  # (gives the GIL up: the walker gets into its kernel)
            start = time.clock_gettime(clock)
            t0 = time.perf_counter()
            ran = 0.0
            while time.perf_counter() - t0 < 1.0 and ran < 0.1 and walker.is_alive():
                ran = time.clock_gettime(clock) - start
            best = max(best, ran)
            if best >= 0.1 or not walker.is_alive():
                break
    finally:
        sys.setswitchinterval(old)
        raycast._compiled[0] = real
        walker.join()
    assert best >= 0.1, f"the walker ran {best * 1000:.0f} ms of CPU while this thread held the GIL"
