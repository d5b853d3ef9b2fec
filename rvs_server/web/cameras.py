"""The newest camera frames for the console's camera panel: the ToF's amplitude and depth, the
stereo pair's left image and each body hazard camera pair's left image.

They come from what the server already publishes on its bus (a driver grab's ``frame`` item,
the same source as Foxglove's images), never from a grab of the page's own: watching the page
costs the devices nothing. The bus calls in the grabbing thread, so only a copy of the image
is kept there (the job may reuse its arrays); encoding to PNG or JPEG happens when a page asks,
in the executor, once per frame however many pages ask.
"""

from __future__ import annotations

import itertools
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from drivers.call_images import images_of

if TYPE_CHECKING:
    from ..bus import Item

MAX_SIDE = 1024  # larger images are reduced: the panel is a few hundred pixels wide
JPEG_QUALITY = 85
TOF = ("tof_amplitude", "tof_depth")
HINTS = {"tof_amplitude": "grab-tof -type amplitude, or a DEM from the ToF",
         "tof_depth": "grab-tof -type z (or distance), or a DEM from the ToF",
         "stereo_left": "grab-stereo, or a DEM from the stereo pair"}
DEPTH_KINDS = {"z": "z", "xyz": "z", "distance": "radial distance"}  # a -type that makes a depth image: what it is


@dataclass(frozen=True)
class Frame:
    image: np.ndarray
    kind: str  # what the values are: amplitude, z, distance, image
    seq: int  # grows with every frame kept: the page's version of the image
    t: float  # when it was grabbed, s since the epoch


@dataclass(frozen=True)
class Encoded:
    body: bytes
    content_type: str
    seq: int
    caption: str  # what the page writes under the image: the kind, the range of a ToF image, the size


def label_of(name: str) -> str:
    return name.replace("_", " ").replace("tof", "ToF")


def file_of(name: str) -> str:
    """The image's file name in the URL: lossless PNG for the ToF's measurements, JPEG for cameras."""
    return f"{name}.png" if name in TOF else f"{name}.jpg"


def frames_of(device: str, call: str, args: tuple[Any, ...], result: Any) -> list[tuple[str, np.ndarray, str]]:
    """(camera name, image, kind) of the images of a driver call's result that the panel shows:
    the ToF's amplitude and depth (the z of its points), each camera pair's left image."""
    out: list[tuple[str, np.ndarray, str]] = []
    for image in images_of(device, call, args, result):
        if device == "tof":
            if image.what == "amplitude":
                out.append(("tof_amplitude", image.image, image.what))
            elif image.what in DEPTH_KINDS:
                out.append(("tof_depth", image.image[..., 2] if image.what == "xyz" else image.image, image.what))
        elif image.what == "left":
            out.append(("stereo_left" if device == "stereo" else f"hazcam_{image.pair}_left", image.image, "image"))
    return out


class CameraFrames:
    """The newest frame of each camera and its last encoding; thread-safe."""

    def __init__(self) -> None:
        self._frames: dict[str, Frame] = {}
        self._encoded: dict[str, Encoded] = {}
        self._lock = threading.Lock()
        self._encoding = threading.Lock()  # one encoding at a time: a second page waits for the first's
        self._seq = itertools.count(1)

    def accept(self, item: Item) -> None:
        """The bus subscriber (the grabbing thread): keep a copy of each camera image it holds."""
        if item.kind != "frame":
            return
        data = item.data
        try:
            found = frames_of(data["device"], data["call"], tuple(data.get("args") or ()), data["result"])
        except (TypeError, ValueError, AttributeError, IndexError):  # a result of another shape
            return
        for name, image, kind in found:
            frame = Frame(np.array(image), kind, next(self._seq), item.time_ns / 1e9)
            with self._lock:
                self._frames[name] = frame

    def listing(self, hazcam_pairs: list[str]) -> list[dict[str, Any]]:
        """The panel's cameras for the state snapshot: the ToF's, the stereo pair's and each
        running hazard camera pair's (or one that sent a frame), each with its image's URL and
        version once it has a frame, else what makes one."""
        with self._lock:
            frames = dict(self._frames)
        names = [*TOF, "stereo_left", *(f"hazcam_{p}_left" for p in hazcam_pairs)]
        names += sorted(n for n in frames if n not in names)
        out = []
        for name in names:
            entry: dict[str, Any] = {"name": name, "label": label_of(name)}
            frame = frames.get(name)
            if frame is None:
                entry["hint"] = HINTS.get(name, "the see loop grabs it while navigating (navigate -loop see)")
            else:
                entry.update(url=f"/cameras/{file_of(name)}?v={frame.seq}", v=frame.seq, t=round(frame.t, 3))
            out.append(entry)
        return out

    def name_of(self, file: str) -> str | None:
        """The camera a URL's file name shows, if it has a frame."""
        with self._lock:
            return next((n for n in self._frames if file_of(n) == file), None)

    def latest(self, name: str) -> Frame:
        """The newest frame of ``name``; KeyError when there is none."""
        with self._lock:
            return self._frames[name]

    def encoded(self, name: str) -> Encoded:
        """The newest frame of ``name`` encoded (blocking: run it off the event loop); KeyError
        when there is none."""
        frame = self.latest(name)
        with self._encoding:
            done = self._encoded.get(name)
            if done is None or done.seq != frame.seq:
                done = _encode(name, frame)
                self._encoded[name] = done
        return done


def _reduce(image: np.ndarray) -> np.ndarray:
    step = max(1, int(np.ceil(max(image.shape[:2]) / MAX_SIDE)))
    return image[::step, ::step] if step > 1 else image


def _encode(name: str, frame: Frame) -> Encoded:
    image = _reduce(frame.image)
    h, w = image.shape[:2]
    when = time.strftime("%H:%M:%S", time.localtime(frame.t))
    if name in TOF:
        rgba, lo, hi = _tof_rgba(image.astype(np.float32), frame.kind)
        unit = "counts" if frame.kind == "amplitude" else f"m ({DEPTH_KINDS[frame.kind]})"
        caption = f"{_number(lo)}-{_number(hi)} {unit}, {w}x{h}, {when}"
        ok, buf = cv2.imencode(".png", cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA), [cv2.IMWRITE_PNG_COMPRESSION, 1])
        content_type = "image/png"
    else:
        if image.dtype == np.uint16:
            image = (image >> 8).astype(np.uint8)
        elif image.dtype != np.uint8:
            image = np.clip(image, 0, 255).astype(np.uint8)
        if image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
        caption = f"{w}x{h}, {when}"
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        content_type = "image/jpeg"
    if not ok:
        raise ValueError(f"the {name} image could not be encoded")
    return Encoded(buf.tobytes(), content_type, frame.seq, caption)


def _number(v: float) -> str:
    return f"{v:.0f}" if abs(v) >= 100 else f"{v:.3g}"


def _tof_rgba(values: np.ndarray, kind: str) -> tuple[np.ndarray, float, float]:
    """A ToF image as RGBA with its range: amplitude grey, depth on the turbo ramp (near blue, far
    red), both stretched over the 1st to 99th percentile; pixels with no measurement transparent."""
    valid = np.isfinite(values) & (values > 0)
    if valid.any():
        lo, hi = (float(v) for v in np.percentile(values[valid], (1, 99)))
    else:
        lo, hi = 0.0, 1.0
    hi = max(hi, lo + 1e-6)
    scaled = np.zeros(values.shape, np.uint8)
    scaled[valid] = np.clip((values[valid] - lo) / (hi - lo) * 255.0, 0, 255).astype(np.uint8)
    if kind == "amplitude":
        rgb = np.repeat(scaled[..., None], 3, axis=2)
    else:
        rgb = cv2.cvtColor(cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO), cv2.COLOR_BGR2RGB)
    rgba = np.dstack([rgb, np.where(valid, 255, 0).astype(np.uint8)])
    rgba[~valid, :3] = 0
    return rgba, lo, hi
