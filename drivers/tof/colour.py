"""Fake colouring of ToF images for previews (rvs-libtof sect. 4.2.9).

Values below ``low`` get the first colour, above ``high`` the last, and the span in between is
divided evenly: the colour scale runs dark blue, blue, green, yellow, red, dark red (OpenCV's
JET), the grey scale black to white. Undefined pixels (NaN, or -1 in an XYZ image) are black.
"""

from __future__ import annotations

import cv2
import numpy as np

MODES = ("jet", "grey")


def value_range(image: np.ndarray, low: float | None = None, high: float | None = None) -> tuple[float, float]:
    """The colour range to use: the given bounds, or the finite min/max of the image."""
    finite = image[np.isfinite(image)]
    if low is None:
        low = float(finite.min()) if finite.size else 0.0
    if high is None:
        high = float(finite.max()) if finite.size else 1.0
    if not high > low:
        high = low + 1.0
    return float(low), float(high)


def fake_colour(
    image: np.ndarray,
    low: float | None = None,
    high: float | None = None,
    mode: str = "jet",
    order: str = "bgr",
) -> np.ndarray:
    """Map a single-channel image onto a uint8 H x W x 3 colour (or grey) image.

    ``order`` "bgr" suits cv2.imwrite, "rgb" suits most other writers.
    """
    if mode not in MODES:
        raise ValueError(f"colour mode {mode!r} not one of {MODES}")
    if order not in ("bgr", "rgb"):
        raise ValueError(f"colour order {order!r} not 'bgr' or 'rgb'")
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2:
        raise ValueError(f"fake colouring needs a single-channel image, got shape {img.shape}")
    low, high = value_range(img, low, high)
    defined = np.isfinite(img)
    scaled = np.clip((np.where(defined, img, low) - low) / (high - low), 0.0, 1.0)
    u8 = np.rint(scaled * 255.0).astype(np.uint8)
    if mode == "jet":
        out = cv2.applyColorMap(u8, cv2.COLORMAP_JET)
        if order == "rgb":
            out = out[..., ::-1]
    else:
        out = np.repeat(u8[..., None], 3, axis=-1)
    out = np.ascontiguousarray(out)
    out[~defined] = 0
    return out
