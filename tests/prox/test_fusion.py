"""ToF-stereo fusion: the per-point noise models, the image features they read,
the two-sensor fusion with its gate, and the parameters they come from. Cheap: synthetic arrays;
the figures against the simulator's truth are tools/bench/fusion.py's."""

from __future__ import annotations

from dataclasses import fields

import numpy as np
import pytest

from prox_workflows.algorithms.acquire import View
from prox_workflows.algorithms.dem_mosaik import fuse_sensors, local_scatter
from prox_workflows.algorithms.noise import (
    JUMP_CAP,
    STEREO_TERMS,
    TOF_TERMS,
    model_sigmas,
    pixel_features,
    stereo_point_variance,
    tof_point_variance,
)
from prox_workflows.engine import script_parameters
from prox_workflows.grid import GridGeometry, Layers
from prox_workflows.parameters import DemParams
from prox_workflows.steps.dem import PointCorrelation, SensorFusion, mosaic, view_dem

G = GridGeometry(0.02, 0.0, 1.0, 50, 50)


def layers_of(z: np.ndarray, var: float | np.ndarray) -> Layers:
    out = Layers(G)
    out["dem"] = np.asarray(z, np.float32)
    out["measurement_variance"] = np.broadcast_to(np.asarray(var, np.float32), G.shape).copy()
    out["count"] = np.isfinite(out["dem"]).astype(np.int32)
    return out


def test_every_model_term_is_a_declared_parameter_with_its_calibrated_default() -> None:
    names = {f.name for f in fields(DemParams)}
    for prefix, terms in (("tof_noise_", TOF_TERMS), ("stereo_noise_", STEREO_TERMS)):
        assert {prefix + t for t in terms} <= names
    p = DemParams()
    assert model_sigmas(p, "tof")["edge"] == p.tof_noise_edge
    assert model_sigmas(p, "stereo")["disparity"] == p.stereo_noise_disparity
    # the chain's own settings (PointCorrelation, SensorFusion) are the dem script's parameters too
    assert {"tof_cell_correlation", "stereo_cell_correlation", "tof_fuse_scatter", "stereo_fuse_scatter",
            "fuse_gate"} <= {f.name for f in fields(script_parameters("dem"))}


def test_models_grow_with_range_and_stereo_with_depth_squared() -> None:
    p = DemParams()
    sensor = np.zeros(3)
    r = np.array([1.0, 2.0, 4.0])
    pts = np.stack([r * 0.8, np.zeros(3), -r * 0.6], axis=1)  # one ray direction, three ranges
    flat_feats = {"jump": np.zeros(3), "slope": np.zeros(3), "cos_incidence": np.ones(3), "wall": np.zeros(3),
                  "texture": np.full(3, 20.0)}
    amp = 12000.0 / r**2  # amplitude falls as 1 / r^2
    tof = tof_point_variance(pts, sensor, amp, flat_feats, **model_sigmas(p, "tof"))
    assert np.all(np.diff(tof) > 0)
    st = stereo_point_variance(pts, sensor, amp, flat_feats, baseline=0.2, focal=550.0,
                               **{**model_sigmas(p, "stereo"), "floor": 0.0, "incidence": 0.0})
    sigma = np.sqrt(st.astype(np.float64))
    assert sigma[2] / sigma[1] == pytest.approx(4.0, rel=0.05)  # z^2: twice as far, four times the sigma
    weak = stereo_point_variance(pts, sensor, amp, {**flat_feats, "texture": np.full(3, 2.0)}, baseline=0.2,
                                 focal=550.0, **model_sigmas(p, "stereo"))
    assert np.all(weak > st)  # weak texture: a worse match
    edge = tof_point_variance(pts, sensor, amp, {**flat_feats, "jump": np.full(3, 0.05)}, **model_sigmas(p, "tof"))
    near_wall = tof_point_variance(pts, sensor, amp, {**flat_feats, "wall": np.full(3, 0.5)}, **model_sigmas(p, "tof"))
    assert np.all(edge > tof) and np.all(near_wall > tof)


def test_pixel_features_see_edges_walls_and_texture() -> None:
    h, w = 20, 30
    v, u = np.mgrid[0:h, 0:w].astype(float)
    coords = np.stack([2.0 + 0.01 * v, 0.01 * u - 0.15, np.zeros((h, w))], axis=2)  # a floor
    coords[:, 20:, 2] = 0.3  # a 30 cm step up: its edge is a depth edge
    coords[:, 25:, 0] = 2.0 + 0.0 * v[:, 25:]  # and its face stands vertical (x fixed, z varies)
    coords[:, 25:, 2] = 0.3 + 0.01 * v[:, 25:]
    image = np.zeros((h, w))
    image[:, :10] = np.random.default_rng(0).uniform(0, 255, (h, 10))
    f = pixel_features(coords, np.array([0.0, 0.0, 1.0]), image, wall_window=5)
    assert f["jump"][5, 19] == pytest.approx(JUMP_CAP) and f["jump"][5, 5] == pytest.approx(0.0)  # capped
    assert f["slope"][5, 19] == pytest.approx(5.0)  # capped
    assert f["wall"][10, 27] > 0.5 and f["wall"][10, 3] == 0.0
    assert f["texture"][10, 3] > 30 and f["texture"][10, 15] == pytest.approx(0.0, abs=1e-3)
    coords[3, 3] = np.nan
    assert np.isnan(pixel_features(coords, np.zeros(3))["jump"][3, 3])


def test_fusion_weighs_each_sensor_by_its_variance_and_beats_both() -> None:
    rng = np.random.default_rng(1)
    truth = np.zeros(G.shape)
    s_tof, s_st = 0.004, 0.006
    tof = layers_of(truth + rng.normal(0, s_tof, G.shape), s_tof**2)
    st = layers_of(truth + rng.normal(0, s_st, G.shape), s_st**2)
    fused = fuse_sensors([tof, st], gate=3.0)

    def rmse(a: np.ndarray) -> float:
        return float(np.sqrt(np.mean((a - truth) ** 2)))
    assert rmse(fused["dem"]) < rmse(tof["dem"]) and rmse(fused["dem"]) < rmse(st["dem"])
    expected = np.sqrt(1 / (1 / s_tof**2 + 1 / s_st**2))
    assert rmse(fused["dem"]) == pytest.approx(expected, rel=0.1)
    # the cells the gate passed (a few per thousand are conflicts and keep one sensor's variance)
    agreed = np.abs(tof["dem"] - st["dem"]) / np.hypot(s_tof, s_st) <= 3.0
    assert agreed.mean() > 0.98
    assert np.allclose(fused["variance"][agreed], expected**2, rtol=1e-3)
    swapped = fuse_sensors([st, tof], gate=3.0)  # order-free
    assert np.allclose(swapped["dem"], fused["dem"], atol=1e-6)


def test_a_conflict_goes_to_the_sensor_the_neighbours_support_not_the_first_or_the_precise() -> None:
    truth = np.zeros(G.shape)
    tof = layers_of(truth.copy(), 0.002**2)
    st = layers_of(truth.copy(), 0.004**2)
    tof["dem"][10, 10] = 0.2  # a ToF outlier (a flying pixel), though ToF claims the smaller variance
    st["dem"][30, 30] = -0.15  # a stereo mismatch
    only = np.full(G.shape, np.nan, np.float32)
    only[40:, :] = 0.01
    tof["dem"][45, 5] = np.nan  # a cell the stereo pair alone sees
    for pair in ([tof, st], [st, tof]):
        fused = fuse_sensors(pair, gate=2.5)
        assert fused["dem"][10, 10] == pytest.approx(0.0, abs=1e-6)
        assert fused["dem"][30, 30] == pytest.approx(0.0, abs=1e-6)
        assert fused["dem"][45, 5] == pytest.approx(0.0, abs=1e-6)
        assert fused.meta["conflicts"] == 2
    lone = layers_of(np.full(G.shape, np.nan), 0.002**2)
    lone["dem"][5, 5] = 0.3
    far = layers_of(np.full(G.shape, np.nan), 0.004**2)
    far["dem"][5, 5] = 0.0
    assert fuse_sensors([lone, far])["dem"][5, 5] == pytest.approx(0.3)  # no neighbours: the smaller variance
    with pytest.raises(ValueError, match="two DEMs"):
        fuse_sensors([tof])


def test_a_cell_off_its_own_neighbours_loses_weight_by_the_scatter_term() -> None:
    truth = np.zeros(G.shape)
    tof = layers_of(truth.copy(), 0.01**2)
    st = layers_of(truth.copy(), 0.01**2)
    tof["dem"][20, 20] = 0.03  # a heavy-tail ToF cell the gate passes (2.1 sigma of the difference)
    tof["dem"][0, 0] = np.nan
    s = local_scatter(np.asarray(tof["dem"]))
    assert s[20, 20] == pytest.approx(0.03**2, rel=1e-5) and s[21, 21] == 0.0 and s[0, 0] == 0.0
    plain = fuse_sensors([tof, st], gate=3.0)
    assert plain["dem"][20, 20] == pytest.approx(0.015, abs=1e-6)  # the model alone: halfway
    fused = fuse_sensors([tof, st], gate=3.0, scatter=(1.0, 1.0))
    expected = 0.03 * 0.01**2 / (2 * 0.01**2 + 0.03**2)  # the ToF cell's variance gained 0.03^2
    assert fused["dem"][20, 20] == pytest.approx(expected, rel=1e-4)
    assert fused["variance"][20, 20] > plain["variance"][20, 20]
    swapped = fuse_sensors([st, tof], gate=3.0, scatter=(1.0, 1.0))  # order-free with its coefficients
    assert np.allclose(swapped["dem"], fused["dem"], atol=1e-7, equal_nan=True)
    assert fused["dem"][21, 21] == pytest.approx(0.0, abs=1e-7)  # neighbours of it keep their weights
    with pytest.raises(ValueError, match="scatter"):
        fuse_sensors([tof, st], scatter=(1.0, -1.0))


def _view(sensor: str, z: np.ndarray, var: float, index: int) -> View:
    xs, ys = np.meshgrid(np.arange(10) * 0.02 + 0.01, 0.99 - np.arange(10) * 0.02)
    pts = np.stack([xs.ravel(), ys.ravel(), z.ravel(), np.full(100, 100.0)], axis=1).astype(np.float32)
    pts = np.repeat(pts, 4, axis=0)  # four points a cell
    return View(index, sensor, 0.0, 0.0, "", pts, np.full(len(pts), var, np.float32), np.ones(len(pts), np.float32),
                np.zeros((3, 4)), np.zeros((10, 10)), np.zeros((10, 10)), np.eye(4))


def test_view_dem_correlation_and_the_two_sensor_mosaic() -> None:
    z = np.zeros((10, 10))
    tv = _view("tof", z, 1e-4, 0)
    independent = view_dem(tv, 0.02, settings=PointCorrelation(0.0, 0.0))
    correlated = view_dem(tv, 0.02, settings=PointCorrelation(1.0, 0.0))
    n = correlated["count"][np.isfinite(correlated["dem"])]
    assert np.all(n == 4)
    ratio = correlated["measurement_variance"] / independent["measurement_variance"]
    assert np.nanmax(np.abs(ratio - 4.0)) < 1e-4  # fully correlated: the mean is no better than one point
    assert view_dem(_view("left", z, 1e-4, 1), 0.02, settings=PointCorrelation(1.0, 0.0))[
        "measurement_variance"][0, 0] == pytest.approx(independent["measurement_variance"][0, 0])
    sv = _view("left", z + 0.001, 4e-4, 1)
    alone = PointCorrelation(0.0, 0.0)
    m = mosaic([view_dem(tv, 0.02, settings=alone), view_dem(sv, 0.02, settings=alone)], None, "fuse", 0.02,
               "inflate", SensorFusion(0.0, 0.0, 2.5))
    assert m.meta["rule"] == "fuse_sensors"
    cell = m["dem"][np.isfinite(m["dem"])]
    assert np.allclose(cell, 0.001 * 1e-4 / 5e-4, atol=1e-6)  # 1 : 4 by the variances
