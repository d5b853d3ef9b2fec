"""The lens distortion map a stereo grab makes at a new resolution: a break (its ``check``
raising) stops it before any work the size of the frame, and the map made in bands is the
whole-frame inverse of OpenCV's distortion."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from drivers.stereo import imaging

K = np.array([[1400.0, 0.0, 959.5], [0.0, 1400.0, 539.5], [0.0, 0.0, 1.0]])
D = np.array([-0.12, 0.05, 0.001, -0.0005, 0.0])


class Stop(Exception):
    pass


def test_a_check_that_stops_at_once_leaves_no_frame_sized_work_done() -> None:
    """At the highest resolution (1920 x 1080) a grid of every pixel's coordinates is 33 MB and
    a good share of a second on a busy machine; none of it may come before the first check."""

    def check() -> None:
        raise Stop

    tracemalloc.start()
    try:
        with pytest.raises(Stop):
            imaging._distortion_map(K, D, (1920, 1080), check)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000, peak  # bytes allocated before the first check


def test_each_band_lays_out_only_its_own_pixels(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[int] = []
    band_pixels: list[int] = []
    real = imaging._undistort_pixels

    def counting(pts: np.ndarray, *args: object) -> np.ndarray:
        band_pixels.append(len(pts))
        return real(pts, *args)

    def check() -> None:
        calls.append(1)
        if len(calls) == 3:
            raise Stop

    monkeypatch.setattr(imaging, "_undistort_pixels", counting)
    with pytest.raises(Stop):
        imaging._distortion_map(K, D, (1920, 1080), check)
    rows = imaging.MAP_BAND_PIXELS // 1920
    assert band_pixels == [rows * 1920, rows * 1920]


def test_the_map_made_in_bands_is_opencvs_inverse_of_every_pixel(monkeypatch: pytest.MonkeyPatch) -> None:
    w, h = 320, 250  # rows not a multiple of the band
    k = K.copy()
    k[0, 2], k[1, 2] = (w - 1) / 2, (h - 1) / 2
    k[0, 0] = k[1, 1] = 300.0
    monkeypatch.setattr(imaging, "MAP_BAND_PIXELS", 7 * w)
    made = imaging._distortion_map(k, D, (w, h), None)
    us, vs = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pts = np.stack([us.ravel(), vs.ravel()], axis=1).reshape(-1, 1, 2)
    und = imaging._undistort_pixels(pts, k, D).reshape(h, w, 2)  # the whole frame at once
    left = made.K_render[0, 2] - k[0, 2]
    top = made.K_render[1, 2] - k[1, 2]
    assert made.map_x is not None and made.map_y is not None
    np.testing.assert_array_equal(made.map_x, (und[..., 0] + left).astype(np.float32))
    np.testing.assert_array_equal(made.map_y, (und[..., 1] + top).astype(np.float32))
    assert made.render_size[0] > w and made.render_size[1] > h  # barrel distortion: margins
