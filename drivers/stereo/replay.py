"""The stereo pair replayed from a recording (drivers/replay.py): each triggered or direct grab
gets the next recorded pair (or single image) as the cameras delivered it, and the calibration
is the one the recorded run reported, so the front end (:class:`drivers.stereo.pair.StereoPair`)
and everything above it run as they did. A grab at another resolution or pixel format than the
recorded one, from another pointing, or past the recording's end is a DeviceError saying so.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.base import DeviceError
from drivers.registry import Capability
from drivers.replay import Call, Replay, ReplaySettings, open_replay
from drivers.stereo.backend import BACKENDS
from drivers.stereo.modes import channels
from drivers.stereo.settings import CameraSettings

GRABS = ("grab_stereo", "grab_mono", "grab_stereo_direct", "grab_mono_direct")
MATRICES = ("K1", "D1", "K2", "D2", "R", "T")  # the rest (image_size, source) as recorded
GUIDS = ("000a4701ffff0001", "000a4701ffff0002")  # the left mount's, the right mount's (no camera's)


@BACKENDS.backend("replay")
class ReplayCameras:
    """Two cameras whose frames come from a recording; TRUTH: the recorded calibration."""

    settings = ReplaySettings
    capabilities = frozenset({Capability.TRUTH})

    def __init__(self, config: Any, world: Any = None) -> None:
        self._file = config.replay_file
        self._timing = config.replay_timing
        self._replay: Replay | None = None

    def open(self) -> list[str]:
        self._replay = open_replay("stereo", self._file)
        return list(GUIDS)

    def available(self) -> list[str]:
        return list(GUIDS) if self._replay is not None else []

    def close(self) -> None:
        self._replay = None

    def describe(self, guid: str) -> dict[str, Any]:
        return {"vendor": "AVT (replayed)", "model": "PIKE F-210B", "mount": _side(guid)}

    def apply_settings(self, guid: str, settings: CameraSettings) -> None:
        _side(guid)

    def hardware_reset(self, guids: list[str]) -> None:
        pass

    def check(self, guids: list[str]) -> dict[str, Any]:
        self._run()
        return {g: {"responding": True, "replay": self._run().recording.path.name} for g in guids}

    def arm(self, guids: list[str], size: tuple[int, int], pixel_format: str) -> dict[str, Any]:
        self._run()
        return {"guids": list(guids), "size": size, "format": pixel_format}

    def disarm(self, token: dict[str, Any]) -> None:
        pass

    def collect(self, token: dict[str, Any], timeout: float, cancel: Any = None) -> dict[str, np.ndarray]:
        return self._serve(token["guids"], token["size"], token["format"])

    def capture_direct(self, guids: list[str], size: tuple[int, int], pixel_format: str, timeout: float,
                       cancel: Any = None) -> dict[str, np.ndarray]:
        return self._serve(guids, size, pixel_format)

    def last_shutter(self) -> dict[str, float]:
        return {}  # a recording keeps the images, not the shutter they really had

    def calibration(self, left: str, right: str, size: tuple[int, int]) -> dict[str, Any]:
        run = self._run()
        for calib in run.fact("stereo_calibration", "stereo").values():
            if tuple(calib["image_size"]) == tuple(size):
                return {key: np.asarray(v, float) if key in MATRICES else v for key, v in calib.items()}
        raise DeviceError("stereo", f"the recording {run.recording.path.name} holds no stereo calibration for "
                                    f"{size[0]}x{size[1]} (the resolution it was grabbed at has one)")

    def _run(self) -> Replay:
        if self._replay is None:
            raise DeviceError("stereo", "the replayed cameras are not open; run reinit or reset")
        return self._replay

    def _serve(self, guids: list[str], size: tuple[int, int], pixel_format: str) -> dict[str, np.ndarray]:
        run = self._run()
        call = run.next("stereo", GRABS, self._timing)
        run.check_pointing(call)
        out: dict[str, np.ndarray] = {}
        for guid in guids:
            side = _side(guid)
            image = call.images.get(side)
            if image is None:
                raise DeviceError("stereo", f"{call.at()} holds no {side} image: the replay asks for another grab "
                                            "than the recorded run made")
            _check_mode(call, image, size, pixel_format)
            out[guid] = image.copy()
        return out


def _side(guid: str) -> str:
    if guid not in GUIDS:
        raise DeviceError("stereo", f"no replayed camera {guid}; the replay's are {', '.join(GUIDS)} (left, right)")
    return ("left", "right")[GUIDS.index(guid)]


def _check_mode(call: Call, image: np.ndarray, size: tuple[int, int], pixel_format: str) -> None:
    has = (image.shape[1], image.shape[0]), (image.shape[2] if image.ndim == 3 else 1)
    if has != (tuple(size), channels(pixel_format)):
        fmt = "rgb8" if has[1] == 3 else "mono8"
        raise DeviceError("stereo", f"{call.at()} was grabbed at {has[0][0]}x{has[0][1]} {fmt}; this grab asks "
                                    f"{size[0]}x{size[1]} {pixel_format}: the recording holds no such frame")
