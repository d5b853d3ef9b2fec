"""Replaying a recording: what every device kind's ``replay`` backend shares.

A recording (``record -start``, an MCAP file) holds every device call a job made on
``/raw/calls`` (its arguments, a result that is no image, where the PTU and the rover were),
followed by the call's frames in full resolution on ``/raw/<device>/...``, the believed pose on
``/rover/pose``, and in its metadata what no message carries: the configuration, where the PTU
and the rover started, the calibrations. :class:`Recording` reads that once per file; a
:class:`Replay` is one run through it, shared by the backends of one server, each taking its
device's calls in recorded order.

A backend is chosen and pointed at a file per device (``drivers.tof.backend=replay``,
``drivers.tof.replay_file=...``), so one device can replay while the others are real or
simulated. ``replay_timing`` serves each call no earlier than its recorded time after the
recording's start (``recorded``), or at once (``fast``). What the recording cannot answer (a
call past its end, a frame from where the PTU never pointed, another resolution) is a
DeviceError saying so; the server answers E_DEVICE and goes on serving.
"""

from __future__ import annotations

import functools
import json
import threading
import time
import weakref
from collections.abc import Generator, Iterator
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from drivers.base import CALL_CANCEL, DeviceError, DeviceInterrupted
from rvs_params import Settings, param

TIMINGS = ("fast", "recorded")
PTU_TOLERANCE_DEG = 0.03  # about half a D46 position: the PTU is where a frame was taken
_DTYPES = {"32FC": np.float32, "mono8": np.uint8, "rgb8": np.uint8, "mono16": np.uint16, "rgb16": np.uint16}


@dataclass
class ReplaySettings(Settings):
    """The keys every replay backend reads (declared once, composed into each device's section)."""

    replay_file: str | None = param(None, "replay: the MCAP recording (record -start) this device's frames and "
                                          "states come from")
    replay_timing: str = param("fast", "replay: fast (each frame as soon as it is asked for) or recorded (no "
                                       "earlier than its recorded time after the recording's start)",
                               choices=TIMINGS)


@dataclass
class Call:
    """One recorded device call and the frames it returned (topic tail -> image)."""

    index: int  # among its device's calls
    t_ns: int
    device: str
    call: str
    args: list[Any]
    result: Any
    ptu: tuple[float, float] | None
    images: dict[str, np.ndarray] = field(default_factory=dict)

    def at(self) -> str:
        return f"{self.device} call {self.index + 1} ({self.call} {', '.join(map(str, self.args))})"


class Recording:
    """A recording's device calls, poses and metadata, read front to back (a file whose writer
    was killed reads up to its last whole record)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.calls: dict[str, list[Call]] = {}
        self.poses: list[tuple[int, float, float, float]] = []  # (t_ns, x, y, heading): the believed pose
        self.requests: list[str] = []  # the request lines received, in order
        self.start_ns: int | None = None
        self.metadata: dict[str, Any] = {}
        self.torn = False
        decoders: dict[int, Any] = {}
        last: Call | None = None
        for schema, channel, message in self._records():
            if channel.message_encoding == "cdr":
                raise DeviceError("replay", not_replayable_ros2(path))
            self.start_ns = message.log_time if self.start_ns is None else min(self.start_ns, message.log_time)
            topic = channel.topic
            if topic == "/raw/calls":
                rec = json.loads(message.data)
                calls = self.calls.setdefault(rec["device"], [])
                ptu = rec.get("ptu")
                last = Call(len(calls), message.log_time, rec["device"], rec["call"], rec["args"], rec.get("result"),
                            None if ptu is None else (float(ptu[0]), float(ptu[1])))
                calls.append(last)
            elif topic.startswith("/raw/") and last is not None and message.log_time == last.t_ns:
                last.images[topic.removeprefix(f"/raw/{last.device}/")] = _image(decoder(decoders, schema)(message.data))
            elif topic == "/rvs/wire":
                wire = json.loads(message.data)
                if wire.get("dir") == "request":
                    self.requests.append(str(wire.get("line", "")))
            elif topic == "/rover/pose":
                pose = decoder(decoders, schema)(message.data).pose
                q = pose.orientation
                heading = float(np.degrees(np.arctan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y ** 2 + q.z ** 2))))
                self.poses.append((message.log_time, pose.position.x, pose.position.y, heading))
        started = self.metadata.get("started")
        if isinstance(started, str):  # record -start's time: the latched maps it begins with are older
            self.start_ns = round(datetime.fromisoformat(started).timestamp() * 1e9)

    def _records(self) -> Iterator[tuple[Any, Any, Any]]:
        try:
            f = open(self.path, "rb")  # noqa: SIM115 - closed below, after the generator's last record
        except OSError as exc:
            raise DeviceError("replay", f"recording {self.path} cannot be read: {exc.strerror or exc}") from None
        with f:
            def metadata(name: str, data: dict[str, str]) -> None:
                if name == "rvs":
                    self.metadata = {k: _json(v) for k, v in data.items()}

            self.torn = yield from mcap_messages(f, metadata)

    def describe(self) -> str:
        counts = ", ".join(f"{len(v)} {k}" for k, v in sorted(self.calls.items()))
        return f"{self.path.name} ({counts or 'no device calls'}{', torn at its end' if self.torn else ''})"


@functools.lru_cache(maxsize=4)
def _load(path: Path, mtime_ns: int, size: int) -> Recording:
    return Recording(path)


def not_replayable_ros2(path: str | Path) -> str:
    """Why a ``ros2``-profile recording does not replay (one line, what to do)."""
    return (f"{path} is a ros2-profile recording (record -profile ros2), for ROS 2's tools; a replay reads "
            "the foxglove profile: record the run again with record -start -profile foxglove")


def load(path: str | Path) -> Recording:
    """The recording at ``path``, read once while the file stays the same."""
    p = Path(path).expanduser().resolve()
    if (p / "metadata.yaml").is_file():  # a rosbag2 directory: what record -profile ros2 writes
        raise DeviceError("replay", not_replayable_ros2(path))
    try:
        st = p.stat()
    except OSError as exc:
        raise DeviceError("replay", f"recording {path} cannot be read: {exc.strerror or exc}") from None
    return _load(p, st.st_mtime_ns, st.st_size)


class Replay:
    """One run through a recording, shared by the backends replaying from it: each device's
    position in its calls, where the replayed PTU is, the recorded time served last."""

    def __init__(self, recording: Recording) -> None:
        self.recording = recording
        self.lock = threading.Lock()
        self.cursors: dict[str, int] = {}
        self.ptu_at: tuple[float, float] | None = None  # told by a replayed PTU as it moves
        self.placed = False  # the replayed rover was set down where the recorded one started
        self.last_ns = recording.start_ns or 0
        self._wall0: float | None = None
        # rvs-replay --mcap's gate: only calls recorded before this time are served (the requests
        # recorded before them were sent); None: no gate, every call as it comes
        self.allowed_ns: int | None = None
        self.turn = threading.Condition(self.lock)

    def next(self, device: str, calls: tuple[str, ...], timing: str) -> Call:
        """The device's next recorded call among ``calls``, paced by ``timing``; DeviceError
        past the recording's end."""
        rec = self.recording
        with self.lock:
            mine = rec.calls.get(device, [])
            i = self.cursors.get(device, 0)
            while i < len(mine) and mine[i].call not in calls:
                i += 1
            self._await_turn(device, mine[i].t_ns if i < len(mine) else None)
            if i >= len(mine):
                self.cursors[device] = i
                served = sum(1 for c in mine if c.call in calls)
                raise DeviceError(device, f"the recording {rec.describe()} holds {served} {device} frame call(s) "
                                          f"and all were served: nothing recorded answers this one (the replay "
                                          f"asks for more than the recorded run did)")
            self.cursors[device] = i + 1
            call = mine[i]
            self.last_ns = max(self.last_ns, call.t_ns)
        self.pace(call.t_ns, timing)
        return call

    def allow(self, t_ns: int | None) -> None:
        """Serve the calls recorded before ``t_ns`` (None: every call, and say past the end)."""
        with self.turn:
            self.allowed_ns = t_ns
            self.turn.notify_all()

    def _await_turn(self, device: str, t_ns: int | None) -> None:
        """Hold a monitor's call back (lock held) while the gate is shut for it: a call the
        recorded run made after a request the replay has not sent yet, or one it never made
        while requests are still to come (a cycle the recorded stop cut short). Its stop (the
        caller's CALL_CANCEL) ends the wait as an interruption. A job's calls are not held: the
        replay sends the requests after a job as the recorded run did (on its final line or
        ACK), and a job that asks for more than was recorded hears so at once."""
        cancel = CALL_CANCEL.get()
        if cancel is None:
            return
        while self.allowed_ns is not None and (t_ns is None or t_ns >= self.allowed_ns):
            if cancel is not None and cancel.is_set():
                raise DeviceInterrupted(device, "stopped while its frame waited for its recorded turn")
            self.turn.wait(0.01)

    def behind(self, t_ns: int) -> bool:
        """Whether a frame call recorded before ``t_ns`` is still to be served: a request recorded
        after a monitor's cycles waits for the replay's monitor to have made them."""
        with self.lock:
            for device, calls in self.recording.calls.items():
                due = [c.index for c in calls if c.images and c.t_ns < t_ns]
                if due and self.cursors.get(device, 0) <= due[-1]:
                    return True
        return False

    def check_pointing(self, call: Call) -> None:
        """DeviceError unless the replayed PTU points where the recorded frame was taken."""
        here, there = self.ptu_at, call.ptu
        if here is None or there is None:
            return
        if max(abs(here[0] - there[0]), abs(here[1] - there[1])) > PTU_TOLERANCE_DEG:
            raise DeviceError(call.device, f"{call.at()} of {self.recording.path.name} was taken at pan "
                                           f"{there[0]:.3f} tilt {there[1]:.3f} deg; the PTU is at pan {here[0]:.3f} "
                                           f"tilt {here[1]:.3f}: the recording holds no frame from here")

    def pace(self, t_ns: int, timing: str) -> None:
        """With recorded timing, wait until ``t_ns`` is as far from now as from the recording's
        start (the clock starts at the first call paced)."""
        if timing != "recorded":
            return
        with self.lock:
            if self._wall0 is None:
                self._wall0 = time.monotonic()
            due = self._wall0 + (t_ns - (self.recording.start_ns or t_ns)) / 1e9
        time.sleep(max(0.0, due - time.monotonic()))

    def fact(self, key: str, device: str) -> Any:
        """A metadata entry the backend needs; DeviceError naming it when the recording lacks it."""
        value = self.recording.metadata.get(key)
        if value is None:
            raise DeviceError(device, f"the recording {self.recording.path.name} holds no {key} (recorded by an "
                                      "older server, or without that device); record the run again")
        return value


_RUNS: weakref.WeakValueDictionary[Path, Replay] = weakref.WeakValueDictionary()
_RUNS_LOCK = threading.Lock()


def open_replay(device: str, path: str | None) -> Replay:
    """The run through ``path`` the other replay backends of this server share: one lives while
    a backend holds it, so the next server (or the same one after all its replay devices were
    closed and dropped) starts from the recording's beginning, and a device's reinit does not."""
    if not path:
        raise DeviceError(device, f"no recording to replay: set drivers.{device}.replay_file to an MCAP file "
                                  "(record -start writes them under the data directory's recordings/)")
    recording = load(path)
    if not recording.calls and not recording.poses:
        raise DeviceError(device, f"{path} holds no device calls to replay (is it an rvs recording?)")
    with _RUNS_LOCK:
        run = _RUNS.get(recording.path)
        if run is None or run.recording is not recording:
            run = Replay(recording)
            _RUNS[recording.path] = run
        return run


def running(path: str | Path) -> Replay | None:
    """The run through the recording at ``path`` that this process's replay backends share, if any."""
    with _RUNS_LOCK:
        return _RUNS.get(Path(path).expanduser().resolve())


def mcap_messages(f: Any, metadata: Any = None) -> Generator[tuple[Any, Any, Any], None, bool]:
    """(schema, channel, message) of every message of an open MCAP file, front to back, also of one
    whose writer was killed (no summary, a torn last record): up to the first torn record. Metadata
    records go to ``metadata(name, data)``. Returns whether the file was torn."""
    from mcap.records import Channel, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    try:
        for record in StreamReader(f, skip_magic=False, emit_chunks=False).records:
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Metadata) and metadata is not None:
                metadata(record.name, record.metadata)
            elif isinstance(record, Message):
                channel = channels[record.channel_id]
                yield schemas.get(channel.schema_id), channel, record
    except Exception:  # noqa: BLE001 - a torn tail fails in the record parser or the decompressor alike
        return True
    return False


def _json(text: str) -> Any:
    try:
        return json.loads(text)
    except ValueError:
        return text


def decoder(cache: dict[int, Any], schema: Any) -> Any:
    """The protobuf parser of a foxglove schema, from the file's own FileDescriptorSet."""
    if schema.id not in cache:
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

        pool = descriptor_pool.DescriptorPool()
        for f in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
            pool.Add(f)
        cache[schema.id] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name)).FromString
    return cache[schema.id]


def _image(msg: Any) -> np.ndarray:
    """A foxglove RawImage as the array the driver returned."""
    encoding = msg.encoding
    dtype = _DTYPES["32FC" if encoding.startswith("32FC") else encoding]
    channels = int(encoding[4:]) if encoding.startswith("32FC") else 3 if encoding.startswith("rgb") else 1
    row = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.step)
    pixels = row[:, : msg.width * channels * np.dtype(dtype).itemsize].copy().view(dtype)
    return pixels.reshape(msg.height, msg.width, channels) if channels > 1 else pixels.reshape(msg.height, msg.width)
