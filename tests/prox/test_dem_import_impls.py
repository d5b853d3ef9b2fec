"""DemImport's implementations against each other: numba's one pass (on one thread and split over
two) and the numpy fallback give the same layers - dem, min and count bit for bit, the moments to
rounding - for every option, dtype and awkward input."""

from __future__ import annotations

import numpy as np
import pytest

import prox_workflows.algorithms.dem_import as dem_import_module
from prox_workflows.algorithms.dem_import import LAYERS, dem_import
from prox_workflows.grid import GridGeometry
from rvs_truth.synthetic import SIDE, tof_scan

pytest.importorskip("numba")

EXACT = ("dem", "min", "count")


def run(impl: str, monkeypatch: pytest.MonkeyPatch, *args, core_free: bool = True, **kwargs):
    monkeypatch.setattr(dem_import_module, "IMPL", impl.split("-")[0])
    monkeypatch.setattr(dem_import_module, "THREADS", 2 if impl == "numba-threads" else 1)
    monkeypatch.setattr(dem_import_module, "THREAD_MIN_POINTS", 0)
    monkeypatch.setattr(dem_import_module, "_core_free", lambda: core_free)
    return dem_import(*args, **kwargs)


def assert_same(a, b, what: str = "") -> None:
    assert a.geometry == b.geometry, what
    assert set(a.layers) == set(b.layers), what
    for name in a.layers:
        x, y = a[name], b[name]
        assert x.dtype == y.dtype and x.shape == y.shape, (what, name)
        if name in EXACT:
            assert np.array_equal(x, y, equal_nan=True), (what, name)
            continue
        assert np.array_equal(np.isnan(x), np.isnan(y)), (what, name)
        ok = np.isfinite(x)
        # sums in a different order (per thread) or from another reference height: rounding only
        scale = np.abs(x[ok]).max(initial=0.0)
        assert np.allclose(x[ok], y[ok], rtol=2e-6, atol=1e-6 * scale + 1e-12), (what, name)


def cloud(rng: np.random.Generator, n: int, dtype, cols: int) -> tuple[np.ndarray, np.ndarray]:
    pts = np.column_stack([rng.uniform(-1.3, 0.7, n), rng.uniform(2.0, 2.9, n), rng.normal(1.5, 0.3, n),
                           rng.uniform(0, 4000, n)])[:, :cols].astype(dtype)
    # points exactly on cell borders, and undefined ones
    pts[: n // 10, 0] = (np.round(pts[: n // 10, 0] / 0.1) * 0.1).astype(dtype)
    pts[n // 10: n // 5, 1] = (np.round(pts[n // 10: n // 5, 1] / 0.1) * 0.1).astype(dtype)
    pts[::97, 0] = np.nan
    pts[::101, 2] = np.inf
    pts[::103, 1] = -np.inf
    return pts, rng.uniform(1e-6, 4e-4, n)


OPTIONS = [
    {},
    {"with_var": True},
    {"rover_mask": (-0.5, 2.2, 0.1, 2.6), "rover_ground_z": 1.5},
    {"rover_mask": [[-1.0, 2.0], [0.5, 2.3], [-0.2, 2.9]], "with_var": True},
    {"bounds": (-1.0, 2.1, 0.5, 2.8)},
    {"geometry": GridGeometry(0.1, -1.0, 2.8, 12, 8)},
    {"geometry": GridGeometry(0.1, -1.0, 2.8, 12, 8), "stats": ("dem",)},
    {"stats": ("dem", "mean", "count")},
    {"stats": ("dem", "min", "variance"), "chunk": 7},
]


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("cols", [3, 4])
@pytest.mark.parametrize("opts", OPTIONS, ids=lambda o: "-".join(o) or "plain")
def test_numba_one_and_two_threads_match_numpy(dtype, cols, opts, monkeypatch) -> None:
    rng = np.random.default_rng(11)
    pts, var = cloud(rng, 20000, dtype, cols)
    opts = dict(opts)
    if opts.pop("with_var", False):
        opts["point_variance"] = var
    ref = run("numpy", monkeypatch, pts, cell=0.1, **opts)
    for impl in ("numba", "numba-threads"):
        assert_same(ref, run(impl, monkeypatch, pts, cell=0.1, **opts), impl)
    assert ref["dem"].size and np.isfinite(ref["dem"]).any()


def test_scan_ordered_tof_points_all_layers(monkeypatch) -> None:
    """The benchmark's synthetic 24-view scan (points in pixel order), with point variances and
    intensity: all eight layers agree, the two-thread pass is taken and changes nothing."""
    pts = tof_scan(200_000)
    rng = np.random.default_rng(3)
    pts4 = np.column_stack([pts, rng.uniform(100, 900, len(pts)).astype(np.float32)])
    var = rng.uniform(1e-6, 1e-4, len(pts))
    g = GridGeometry(0.05, 0.0, SIDE, 200, 200)  # 5 points a cell: the split pays
    ref = run("numpy", monkeypatch, pts4, geometry=g, point_variance=var)
    assert set(ref.layers) == set(LAYERS) | {"measurement_variance", "wmean", "intensity"}
    calls = []
    submit = dem_import_module.ThreadPoolExecutor.submit
    monkeypatch.setattr(dem_import_module.ThreadPoolExecutor, "submit",
                        lambda self, *a, **k: calls.append(1) or submit(self, *a, **k))
    one = run("numba", monkeypatch, pts4, geometry=g, point_variance=var)
    two = run("numba-threads", monkeypatch, pts4, geometry=g, point_variance=var)
    assert calls == [1]
    assert_same(ref, one)
    # each thread scatters into its own cells in the points' order: bit for bit one thread's result
    for name in one.layers:
        assert np.array_equal(one[name], two[name], equal_nan=True), name
    assert ref["count"].sum() == len(pts)


def test_float64_geometry_numbers_with_float32_points(monkeypatch) -> None:
    """cell_of computes in float64 when the geometry holds numpy float64 numbers: so must both."""
    g = GridGeometry(np.float64(0.02), np.float64(-0.1), np.float64(0.1), 10, 10)
    k = np.arange(-5, 6)
    xs, ys = np.meshgrid(k * 0.02, k * 0.02)
    pts = np.column_stack([xs.ravel(), ys.ravel(), np.arange(xs.size, dtype=float)]).astype(np.float32)
    rows, cols = g.cell_of(pts[:, 0], pts[:, 1])
    inside = g.inside(rows, cols)
    counts = np.zeros(g.shape, np.int32)
    np.add.at(counts, (rows[inside], cols[inside]), 1)
    for impl in ("numpy", "numba"):
        assert np.array_equal(run(impl, monkeypatch, pts, geometry=g)["count"], counts), impl


@pytest.mark.parametrize("ground", [0.05, np.float64(0.05)])
def test_rover_ground_height_compares_as_numpy_does(ground, monkeypatch) -> None:
    """A point at float32(0.05) is not above the Python float 0.05 (numpy compares in float32)
    but is above np.float64(0.05): both implementations drop the same points."""
    z = np.float32(0.05)
    pts = np.array([[0.01, 0.01, z], [0.03, 0.01, np.nextafter(z, np.float32(1))], [0.05, 0.01, 0.0]], np.float32)
    g = GridGeometry(0.02, 0.0, 0.02, 3, 1)
    ref = run("numpy", monkeypatch, pts, geometry=g, rover_mask=(0.0, 0.0, 0.1, 0.02), rover_ground_z=ground)
    assert_same(ref, run("numba", monkeypatch, pts, geometry=g, rover_mask=(0.0, 0.0, 0.1, 0.02),
                         rover_ground_z=ground))
    assert ref["count"][0].tolist() == ([1, 0, 1] if isinstance(ground, float) and not isinstance(ground, np.floating)
                                        else [0, 0, 1])


def test_no_points_on_a_given_grid(monkeypatch) -> None:
    g = GridGeometry(0.1, 0.0, 1.0, 10, 10)
    for impl in ("numpy", "numba"):
        layers = run(impl, monkeypatch, np.zeros((0, 3), np.float32), geometry=g)
        assert np.all(np.isnan(layers["dem"])) and np.all(layers["count"] == 0), impl
    with pytest.raises(ValueError):
        run("numba", monkeypatch, np.full((3, 3), np.nan))


def test_warm_up_compiles_every_variant() -> None:
    dem_import_module.warm_up()
    kernels = dem_import_module._kernels()
    assert kernels is not None
    assert len(kernels["accumulate"].signatures) >= 2  # float32 and float64 points


def test_second_half_runs_here_when_the_worker_is_busy(monkeypatch) -> None:
    """If the worker has not started the second half when the first is done (another caller
    keeps it busy), the calling thread does it: same result, no waiting."""
    import threading
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(12)
    pts, var = cloud(rng, 5000, np.float32, 4)
    ref = run("numpy", monkeypatch, pts, cell=0.1, point_variance=var)
    busy = ThreadPoolExecutor(max_workers=1)
    gate = threading.Event()
    busy.submit(gate.wait)
    monkeypatch.setattr(dem_import_module, "_pool", lambda: busy)
    try:
        got = run("numba-threads", monkeypatch, pts, cell=0.1, point_variance=var)
    finally:
        gate.set()
        busy.shutdown()
    assert_same(ref, got)


def test_kept_sums_are_clean_for_the_next_call(monkeypatch) -> None:
    """The float64 sums are reused between calls on a thread (zeroed again by the finishing
    pass): calls of other sizes and options, and one that fails half-way, leave no trace."""
    rng = np.random.default_rng(13)
    pts, var = cloud(rng, 20000, np.float32, 4)
    first = run("numba", monkeypatch, pts, cell=0.1, point_variance=var)
    run("numba", monkeypatch, pts[:500, :3], cell=0.02)
    run("numba-threads", monkeypatch, pts, cell=0.05, point_variance=var)
    kernels = dem_import_module._kernels()

    def broken(*args):
        raise RuntimeError("half-way")

    monkeypatch.setitem(kernels, "finish", broken)
    with pytest.raises(RuntimeError):
        run("numba", monkeypatch, pts, cell=0.1, point_variance=var)
    monkeypatch.undo()
    again = run("numba", monkeypatch, pts, cell=0.1, point_variance=var)
    for name in first.layers:
        assert np.array_equal(first[name], again[name], equal_nan=True), name


def test_one_thread_when_no_core_is_free(monkeypatch) -> None:
    pts = tof_scan(50_000)
    calls = []
    submit = dem_import_module.ThreadPoolExecutor.submit
    monkeypatch.setattr(dem_import_module.ThreadPoolExecutor, "submit",
                        lambda self, *a, **k: calls.append(1) or submit(self, *a, **k))
    run("numba-threads", monkeypatch, pts, cell=0.1)
    assert calls == [1]
    run("numba-threads", monkeypatch, pts, cell=0.1, core_free=False)
    assert calls == [1]


def test_without_numba_the_numpy_implementation_serves(monkeypatch) -> None:
    monkeypatch.setattr(dem_import_module, "HAVE_NUMBA", False)
    monkeypatch.setattr(dem_import_module, "_compiled", {})
    monkeypatch.setattr(dem_import_module, "IMPL", "numba")
    assert dem_import_module._kernels() is None
    dem_import_module.warm_up()  # nothing to do
    called = []
    numpy_impl = dem_import_module._import_numpy
    monkeypatch.setattr(dem_import_module, "_import_numpy", lambda *a: called.append(1) or numpy_impl(*a))
    layers = dem_import(np.array([[0.01, 0.01, 1.0], [0.03, 0.01, 2.0]]), cell=0.02)
    assert called == [1] and layers["count"].sum() == 2
