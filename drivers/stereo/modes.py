"""The acquisition modes rvs-libcam-avt offers (seed 000 sect. 4.1.3): four resolutions, two formats.

A bad name is a usage error (ValueError, which the server answers with E_ARG), never a device
error: the camera was not even asked.
"""

from __future__ import annotations

RESOLUTIONS: dict[str, tuple[int, int]] = {
    "low": (640, 480),
    "medium": (1024, 768),
    "high": (1280, 960),
    "highest": (1920, 1080),
}

# YUV formats would need PAL/NTSC-dependent conversions the thesis never wrote; 8-bit only.
PIXEL_FORMATS: tuple[str, ...] = ("mono8", "rgb8")

SIDES: tuple[str, ...] = ("left", "right")


def resolution_size(name: str) -> tuple[int, int]:
    """(width, height) of a resolution mode name."""
    key = str(name).strip().lower()
    if key not in RESOLUTIONS:
        accepted = ", ".join(f"{k} {w}x{h}" for k, (w, h) in RESOLUTIONS.items())
        raise ValueError(f"invalid resolution {name!r}; accepted: {accepted}")
    return RESOLUTIONS[key]


def check_resolution(name: str) -> str:
    resolution_size(name)
    return str(name).strip().lower()


def check_pixel_format(name: str) -> str:
    key = str(name).strip().lower()
    if key not in PIXEL_FORMATS:
        raise ValueError(
            f"invalid pixel format {name!r}; accepted: {', '.join(PIXEL_FORMATS)} "
            "(the PIKE interface supports 8-bit mono and 8-bit RGB only)"
        )
    return key


def channels(pixel_format: str) -> int:
    return 3 if check_pixel_format(pixel_format) == "rgb8" else 1


def check_side(side: str) -> str:
    key = str(side).strip().lower()
    if key not in SIDES:
        raise ValueError(f"invalid camera side {side!r}; accepted: {', '.join(SIDES)}")
    return key
