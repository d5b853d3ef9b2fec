"""The images in what a device call returned, and what each one is.

The server publishes every driver call it makes with its result (``rvs_server.bus``); the
telemetry hub turns the images into Foxglove channels and a recording's ``/raw`` topics, the
web console's camera panel keeps the newest of each camera. Both read a result through
:func:`images_of`, so a call's images are told apart once, next to the devices that return them:
the ToF's ``grab_xyz`` (points and amplitude) and ``grab(image_type)`` (one image of that type),
the stereo pair's two-image and one-image grabs, and a body hazard camera pair's ``images`` and
``grab`` (a :class:`~drivers.hazcam.device.HazcamFrame`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

# The calls, per device, whose results hold images; a device's other calls (a PTU move, a drive) hold none.
IMAGE_CALLS: dict[str, frozenset[str]] = {
    "tof": frozenset({"grab_xyz", "grab"}),
    "stereo": frozenset({"grab_stereo", "grab_stereo_direct", "grab_mono", "grab_mono_direct"}),
    "hazcam": frozenset({"images", "grab"}),
}
SIDES = ("left", "right")


@dataclass(frozen=True)
class CallImage:
    image: np.ndarray  # the result's own array, not a copy
    what: str  # a ToF image's measurement (xyz, amplitude, distance, z, confidence); a camera's side (left, right)
    key: str  # its name among the call's images: a recording keeps it on /raw/<device>/<key>, a replay finds it there
    pair: str | None = None  # the body hazard camera pair it comes from (front, rear)


def carries_images(device: str, call: str) -> bool:
    return call in IMAGE_CALLS.get(device, ())


def images_of(device: str, call: str, args: tuple[Any, ...] | list[Any], result: Any) -> list[CallImage]:
    """The images in ``result`` of ``device.call(*args)``, in the order the call returns them;
    none for a call that returns no image. A result of another shape than the call's raises
    (TypeError, ValueError, AttributeError or IndexError)."""
    if not carries_images(device, call):
        return []
    if device == "tof":
        if call == "grab_xyz":
            xyz, amplitude = result
            return [CallImage(xyz, "xyz", "xyz"), CallImage(amplitude, "amplitude", "amplitude")]
        return [CallImage(result, str(args[0]) if args else "distance", "image")]  # grab(image_type)
    if device == "stereo":
        if call in ("grab_stereo", "grab_stereo_direct"):
            return [CallImage(image, side, side) for side, image in zip(SIDES, result, strict=True)]
        side = str(args[0]) if args else "left"  # grab_mono(side)
        return [CallImage(result, side, side)]
    if call == "images":  # images(pair): the pair's two images
        pair, images = str(args[0]), result
    else:  # grab(pair): a HazcamFrame, which names its pair
        pair, images = result.camera, (result.left, result.right)
    return [CallImage(image, side, f"{pair}/{side}", pair) for side, image in zip(SIDES, images, strict=True)]
