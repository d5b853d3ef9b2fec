"""Real hazard camera pairs on FireWire (IIDC) through libdc1394, as the PIKE pair is driven.

The bus, the Format7 set-up and the frame copies are the stereo pair's backend
(:class:`drivers.stereo.dc1394.Dc1394Cameras`, its settings the library and bus keys here too);
this module only knows which GUIDs make which pair. A pair is captured free-running, both
cameras armed together, so its two frames may lie one frame period apart: a rover that drives
while its hazcams look wants the pair's cameras on one trigger line (a sync cable).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from drivers.base import DeviceError, DeviceInterrupted
from drivers.stereo.dc1394 import Dc1394Cameras, Dc1394Settings
from drivers.stereo.errors import CameraLost, GrabCancelled, MissedTrigger
from rvs_params import param

from .backend import BACKENDS, NAME
from .rig import PairRig


@dataclass
class Dc1394HazcamSettings(Dc1394Settings):
    """drivers.hazcam keys of the FireWire pairs (and the stereo backend's library and bus keys)."""

    front_left_id: str = param("", "dc1394: front pair's left camera GUID (hex)")
    front_right_id: str = param("", "dc1394: front pair's right camera GUID (hex)")
    rear_left_id: str = param("", "dc1394: rear pair's left camera GUID (hex)")
    rear_right_id: str = param("", "dc1394: rear pair's right camera GUID (hex)")
    grab_timeout: float = param(1.0, "dc1394: a grab waits this long for both frames", unit="s", min=0.0,
                                max=3600.0)


@BACKENDS.backend("dc1394")
class Dc1394Hazcams:
    settings = Dc1394HazcamSettings

    def __init__(self, config: Any, world: Any = None, *, lib: Any = None) -> None:
        self._bus = Dc1394Cameras(config, lib=lib)
        self._ids = {side: (str(getattr(config, f"{side}_left_id")).lower().removeprefix("0x").rjust(16, "0"),
                            str(getattr(config, f"{side}_right_id")).lower().removeprefix("0x").rjust(16, "0"))
                     for side in ("front", "rear")}
        self._configured = {side: bool(getattr(config, f"{side}_left_id") and getattr(config, f"{side}_right_id"))
                            for side in ("front", "rear")}
        self.timeout = float(config.grab_timeout)

    def open(self, cameras: tuple[str, ...]) -> None:
        try:
            found = self._bus.open()
        except DeviceError as exc:  # the stereo backend's words, for this device
            raise DeviceError(NAME, exc.message.replace("drivers.stereo.", "drivers.hazcam.")) from exc
        for side in cameras:
            if not self._configured[side]:
                raise DeviceError(NAME, f"set drivers.hazcam.{side}_left_id and {side}_right_id to the GUIDs (hex) "
                                        f"of the {side} pair's cameras; on the bus: {', '.join(found) or 'none'}")
            missing = [g for g in self._ids[side] if g not in found]
            if missing:
                self._bus.close()
                raise DeviceError(NAME, f"{side} pair camera(s) {', '.join(missing)} not on the FireWire bus (found: "
                                        f"{', '.join(found) or 'none'}): check the cables and the camera power, "
                                        f"or drivers.hazcam.{side}_left_id/{side}_right_id")

    def close(self) -> None:
        self._bus.close()

    def check(self, cameras: tuple[str, ...]) -> dict[str, Any]:
        try:
            answers = self._bus.check([g for side in cameras for g in self._ids[side]])
        except CameraLost as exc:
            raise DeviceError(NAME, f"camera {exc.guid} is not answering on the FireWire bus {exc.detail}") from exc
        return {side: {g: answers[g] for g in self._ids[side]} for side in cameras}

    def capture(self, rig: PairRig, cancel: Any = None) -> tuple[np.ndarray, np.ndarray, float]:
        guids = list(self._ids[rig.camera])
        stamp = time.time()
        try:
            frames = self._bus.capture_direct(guids, rig.size, "mono8", self.timeout, cancel)
        except GrabCancelled:
            raise DeviceInterrupted(NAME, "grab cancelled while waiting for the pair's frames") from None
        except (CameraLost, MissedTrigger) as exc:
            raise DeviceError(NAME, f"{exc}: no frame within {self.timeout:g} s; check the cable and the camera "
                                    "power, then reinit -device hazcam") from exc
        except ValueError as exc:  # a size the sensor cannot give
            raise DeviceError(NAME, f"{exc}: set drivers.hazcam.size or sensor_size") from exc
        return frames[guids[0]], frames[guids[1]], stamp
