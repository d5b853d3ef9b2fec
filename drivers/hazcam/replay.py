"""The body hazard cameras replayed from a recording (drivers/replay.py): each grab of a pair gets
the next recorded pair of that end of the rover, the images as the cameras delivered them, and
the front end (:class:`drivers.hazcam.device.Hazcam`) matches them again with the server's
matcher, so the points and everything the see loop makes of them come out as they did. The
pairs do not pan, so unlike the mast's sensors a frame is served wherever the PTU points. A
grab of the other pair than the recorded one, at another size, or past the recording's end is
a DeviceError saying so.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.base import DeviceError
from drivers.replay import Call, Replay, ReplaySettings, open_replay

from .backend import BACKENDS, NAME
from .rig import PairRig

CALLS = ("grab", "images")  # the front end's calls that capture a pair


@BACKENDS.backend("replay")
class ReplayHazcams:
    settings = ReplaySettings

    def __init__(self, config: Any, world: Any = None) -> None:
        self._file = config.replay_file
        self._timing = config.replay_timing
        self._replay: Replay | None = None

    def open(self, cameras: tuple[str, ...]) -> None:
        self._replay = open_replay(NAME, self._file)

    def close(self) -> None:
        self._replay = None

    def check(self, cameras: tuple[str, ...]) -> dict[str, Any]:
        name = self._run().recording.path.name
        return {c: {"responding": True, "replay": name} for c in cameras}

    def capture(self, rig: PairRig, cancel: Any = None) -> tuple[np.ndarray, np.ndarray, float]:
        """The next recorded pair, taken when it was (the recorded stamp: the simulated clock
        for a simulated run; a recording of ``images`` alone keeps none, its log time stands in)."""
        call = self._run().next(NAME, CALLS, self._timing)
        camera = str(call.args[0]) if call.args else ""
        if camera != rig.camera:
            raise DeviceError(NAME, f"{call.at()} was a grab of the {camera} pair; this grab asks for the "
                                    f"{rig.camera} pair: the recording holds no such frame here")
        left, right = (_image(call, f"{camera}/{side}", rig) for side in ("left", "right"))
        stamp = call.result.get("stamp") if isinstance(call.result, dict) else None
        return left, right, float(call.t_ns / 1e9 if stamp is None else stamp)

    def _run(self) -> Replay:
        if self._replay is None:
            raise DeviceError(NAME, "the replayed hazcams are not open; run reinit or reset")
        return self._replay


def _image(call: Call, key: str, rig: PairRig) -> np.ndarray:
    image = call.images.get(key)
    if image is None:
        raise DeviceError(NAME, f"{call.at()} holds no {key} image (the recording lost its frames, or they were "
                                "not recorded): record the run again")
    if (image.shape[1], image.shape[0]) != rig.size:
        raise DeviceError(NAME, f"{call.at()} was grabbed at {image.shape[1]}x{image.shape[0]}; "
                                f"drivers.hazcam.size is {rig.size[0]}x{rig.size[1]}: the recording holds no such "
                                "frame")
    return image.copy()
