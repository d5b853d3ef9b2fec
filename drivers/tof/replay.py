"""The SR4000 replayed from a recording (drivers/replay.py): each recorded grab becomes the raw
frames that make the front end (:class:`drivers.tof.device.Tof`) return exactly the recorded
image, so everything above the camera runs as it did.

A recording holds what the front end returned, not the camera's raw frames: a ``grab_xyz`` of
``integrate`` frames is served as that many equal frames whose mean is the recorded points and
amplitude, bit for bit. A 2-D grab (distance, amplitude, confidence, z) is served as frames that
give the recorded image back to within one raw count (the range to 1/65535 of the unambiguous
range), and exactly for a frame that was itself one raw frame; a camera whose distortion is not
zero has its 2-D images undistorted a second time. The wrap check's frame (at the check
frequency) sees nothing, which keeps the recorded points (their wrapped pixels are already
undefined); with auto exposure on, each grab is given one settling frame. The register settings
are taken and reported, and change nothing in what is served.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.base import DeviceError
from drivers.replay import Call, Replay, ReplaySettings, open_replay

from . import constants as k
from .backend import BACKENDS, DeviceInfo, RawFrame
from .simulated import nominal_camera_matrix

GRABS = ("grab_xyz", "grab")
REPLAY_SERIAL = 0x52455000  # "REP": no camera's


@BACKENDS.backend("replay")
class ReplayTof:
    """The camera at register level, its frames from a recording."""

    settings = ReplaySettings
    rows = k.HEIGHT
    cols = k.WIDTH

    def __init__(self, config: Any, world: Any = None) -> None:
        self._file = config.replay_file
        self._timing = config.replay_timing
        self._replay: Replay | None = None
        self._integration = 30
        self._frequency = 30.0
        self._mode = int(k.AcquireMode.AM_SW_TRIGGER)
        self._auto = False
        self._pending: list[RawFrame] = []
        self._grab: Call | None = None  # the recorded grab the current grab's frames come from
        self._grab_mhz: float | None = None  # the modulation the frames of the last grab were served at

    def open(self, serial: int) -> None:
        self._replay = open_replay("tof", self._file)

    def close(self) -> None:
        self._replay, self._pending = None, []

    @property
    def is_open(self) -> bool:
        """The front end asks this once as each grab starts (and never between its frames): the
        frames a grab that integrated fewer than the recorded one left are dropped here."""
        self._pending, self._grab = [], None
        return self._replay is not None

    def _run(self) -> Replay:
        if self._replay is None:
            raise DeviceError("tof", "the replayed SR4000 is not open; run reinit or reset")
        return self._replay

    def info(self) -> DeviceInfo:
        name = self._run().recording.path.name
        return DeviceInfo(REPLAY_SERIAL, k.SR4000_VENDOR_ID, k.SR4000_PRODUCT_IDS[0], "MESA Imaging",
                          "SR4000 (replayed)", f"SR4000 replayed from {name}")

    def intrinsics(self) -> tuple[np.ndarray, np.ndarray]:
        """The recorded camera's (its matrix and distortion as the run had them)."""
        if self._replay is None:  # asked before open (the front end's calibration): the file, if it reads
            try:
                self._replay = open_replay("tof", self._file)
            except DeviceError:
                return nominal_camera_matrix(self.cols, self.rows), np.zeros(5)
        if not self._replay.recording.calls.get("tof"):  # no frame to project: any matrix does
            return nominal_camera_matrix(self.cols, self.rows), np.zeros(5)
        facts = self._replay.fact("tof_intrinsics", "tof")
        return np.asarray(facts["K"], float), np.asarray(facts["dist"], float)

    # -- registers: taken and reported
    def set_integration(self, register: int) -> None:
        self._integration = k.check_integration(register)

    def get_integration(self) -> int:
        return self._integration

    def set_modulation(self, frequency_mhz: float) -> None:
        self._frequency = k.check_frequency(frequency_mhz)

    def get_modulation(self) -> float:
        return self._frequency

    def set_amplitude_threshold(self, value: int) -> None:
        if not 0 <= int(value) <= k.RAW_MAX:
            raise ValueError(f"amplitude threshold {value} outside 0..65535")

    def set_mode(self, mode: int) -> None:
        self._mode = int(mode)

    def get_mode(self) -> int:
        return self._mode

    def set_auto_exposure(self, min_integration: int, max_integration: int, percent_over: int, desired: int) -> None:
        self._auto = int(min_integration) != 0xFF

    # -- frames
    def acquire(self) -> RawFrame:
        run = self._run()
        if not self._pending and self._grab_mhz is not None and \
                k.WRAP_CHECK_FREQUENCY.get(self._grab_mhz) == self._frequency:
            return self._unseen()  # the wrap check's frame: it contradicts nothing recorded
        if not self._pending:
            if self._grab is not None:
                raise DeviceError("tof", f"{self._grab.at()} was recorded with fewer frames than this grab "
                                         "integrates: the recording holds no more frames for it")
            call = self._grab = run.next("tof", GRABS, self._timing)
            run.check_pointing(call)
            self._grab_mhz = self._frequency
            frames = frames_for(call, k.unambiguous_range(self._frequency), self._integration)
            self._pending = ([frames[0]] if self._auto else []) + frames
        return self._pending.pop(0)

    def _unseen(self) -> RawFrame:
        zeros = np.zeros((self.rows, self.cols), np.uint16)
        return RawFrame(zeros, zeros, zeros, np.zeros((self.rows, self.cols, 3), np.float32), self._integration)


def frames_for(call: Call, rmax: float, integration: int) -> list[RawFrame]:
    """The raw frames whose integration gives the recorded image of ``call`` back."""
    if call.call == "grab_xyz" or (call.args and call.args[0] == "xyz"):
        n = int(call.args[0 if call.call == "grab_xyz" else 1]) if len(call.args) > (call.call != "grab_xyz") else 1
        xyz = call.images.get("xyz", call.images.get("image"))
        amplitude = call.images.get("amplitude")
        if xyz is None:
            raise DeviceError("tof", f"{call.at()} has no recorded points (the recording is torn there)")
        return _xyz_frames(xyz, amplitude, n, rmax, integration)
    kind = str(call.args[0]) if call.args else "distance"
    n = int(call.args[1]) if len(call.args) > 1 else 1
    image = call.images.get("image")
    if image is None:
        raise DeviceError("tof", f"{call.at()} has no recorded image (the recording is torn there)")
    return _image_frames(kind, image, n, rmax, integration)


def _xyz_frames(xyz: np.ndarray, amplitude: np.ndarray | None, n: int, rmax: float,
                integration: int) -> list[RawFrame]:
    """``n`` frames: the same points (their sum over ``n`` divides back exactly), a distance
    that agrees with them (so no pixel counts as straddling the wrap) and full confidence where
    defined; amplitudes split so that their mean is the recorded one."""
    norm = np.linalg.norm(xyz.astype(np.float64), axis=2)
    defined = (xyz[..., 2] != -1.0) & (norm > 0)
    distance = np.where(defined, np.clip(np.rint(norm / rmax * k.RAW_MAX), 1, k.RAW_MAX - 1), 0).astype(np.uint16)
    confidence = np.where(defined, k.RAW_MAX, 0).astype(np.uint16)
    amplitudes = _split(amplitude if amplitude is not None else np.zeros(norm.shape), n)
    points = np.where(defined[..., None], xyz, 0.0).astype(np.float32)
    return [RawFrame(distance, a, confidence, points, integration) for a in amplitudes]


def _image_frames(kind: str, image: np.ndarray, n: int, rmax: float, integration: int) -> list[RawFrame]:
    """``n`` equal frames (amplitudes split) that give a 2-D image back."""
    img = image.astype(np.float64)
    defined = np.isfinite(img)
    shape = img.shape
    distance = np.full(shape, k.RAW_MAX // 2, np.uint16)  # defined, mid-range, for images that carry no range
    confidence = np.full(shape, k.RAW_MAX, np.uint16)
    xyz = np.zeros((*shape, 3), np.float32)
    amplitude = np.zeros(shape)
    if kind == "distance":
        distance = np.clip(np.rint(np.nan_to_num(img) / rmax * k.RAW_MAX), 1, k.RAW_MAX - 1).astype(np.uint16)
    elif kind == "amplitude":
        amplitude = np.nan_to_num(img)
    elif kind == "confidence":
        confidence = np.clip(np.rint(np.nan_to_num(img) * k.RAW_MAX), 0, k.RAW_MAX).astype(np.uint16)
        defined = confidence > 0
    elif kind == "z":
        xyz[..., 2] = np.nan_to_num(img)
    distance = np.where(defined, distance, 0).astype(np.uint16)
    return [RawFrame(distance, a, confidence, xyz, integration) for a in _split(amplitude, n)]


def _split(mean: np.ndarray, n: int) -> list[np.ndarray]:
    """``n`` uint16 images whose mean is ``mean`` as the front end computes it (their sum, to the
    nearest count, over n)."""
    total = np.rint(np.nan_to_num(np.asarray(mean, np.float64)) * n).astype(np.int64)
    base, extra = np.divmod(total, n)
    return [np.clip(base + (extra > i), 0, k.RAW_MAX).astype(np.uint16) for i in range(n)]
