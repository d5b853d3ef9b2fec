"""An MCAP recording: the live channels, plus each device's raw frames in full resolution and
every wire line with its time, written through foxglove-sdk's MCAP writer in the telemetry
process, in Foxglove's schemas or (the ``ros2`` profile) as ROS 2 messages.

The file is written in place (not to a temporary name renamed at the end) because a recording
must be readable after a crash. A SIGKILL of the server closes the telemetry process's pipe,
and the process then finishes the file whole (summary and all) before it exits. Should the
telemetry process itself be killed: messages go into zstd-compressed chunks, a finished chunk
is on disk for good, and the open one is finished at least every :data:`FLUSH_S`, so the file
loses the messages of the last second or so plus the summary (the index and statistics at the
end); an MCAP reader then reads it front to back, as ``mcap recover`` or :func:`read_messages`
here do.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import foxglove
from foxglove.mcap import MCAPCompression, MCAPWriteOptions

from .outlet import Outlet, Topic
from .ros2_messages import ENCODERS
from .ros2_msgs import MESSAGE_ENCODING, SCHEMA_ENCODING, definition, type_name

FLUSH_S = 1.0  # the longest a message waits in the open chunk (what a SIGKILL of the telemetry process loses)
CHUNK_BYTES = 4 * 1024 * 1024  # a chunk is also finished at this uncompressed size


class Recording(Outlet):
    """A recording of the ``foxglove`` profile: every message in Foxglove's schemas, as live."""

    mcap_profile = ""  # the MCAP header's (foxglove's files have none)

    def __init__(self, path: Path, metadata: dict[str, str]) -> None:
        super().__init__(live=False)
        self.declare()
        self.path = path
        self.started = time.monotonic()
        self.start_ns = time.time_ns()
        self.writer = foxglove.open_mcap(path, context=self.context, writer_options=MCAPWriteOptions(
            compression=MCAPCompression.Zstd, chunk_size=CHUNK_BYTES, compression_threads=0,
            profile=self.mcap_profile))
        self.writer.write_metadata("rvs", metadata)
        self._flushed = time.monotonic()

    def log(self, topic: str, data: bytes, t_ns: int) -> None:
        """A message from before the start (what is latched, sent again to the new file: a map,
        the plan; one under way as the recording started) is logged at the start, so that the
        file's time range is the recording's; its content keeps its own time."""
        super().log(topic, data, max(t_ns, self.start_ns))

    def tick(self, now: float) -> None:
        """Finish the open chunk if it is :data:`FLUSH_S` old (``now``: time.monotonic())."""
        if now - self._flushed >= FLUSH_S:
            self._flushed = now
            self.writer.flush()

    def close(self) -> dict[str, Any]:
        """Write the summary; what the file holds."""
        self.writer.close()
        return {"messages": sum(self.counts.values()), "seconds": time.monotonic() - self.started,
                "bytes": self.path.stat().st_size}


class Ros2Recording(Recording):
    """A recording of the ``ros2`` profile, for ROS 2's tools (``ros2 bag info``, ``ros2 bag
    play``): the same messages as ROS 2 messages (:mod:`.ros2_messages`), CDR-encoded, each
    channel's schema the type's full definition (:mod:`.ros2_msgs`). A channel is made with its
    first message, whose encoding gives its type; the rest is as :class:`Recording`."""

    profile = "ros2"
    mcap_profile = "ros2"

    def declare(self) -> None:
        """Nothing ahead: a topic's ROS 2 type is known from its first message."""

    def open_channel(self, topic: str, spec: Topic, encode: Callable[..., bytes] | None) -> foxglove.Channel:
        if encode is None:
            raise KeyError(f"{topic}: a ROS 2 channel is opened by its first message")
        short = ENCODERS[encode][0]
        schema = foxglove.Schema(name=type_name(short), encoding=SCHEMA_ENCODING, data=definition(short).encode())
        return foxglove.Channel(topic, schema=schema, message_encoding=MESSAGE_ENCODING, context=self.context)

    def encode(self, encode: Callable[..., bytes], args: tuple[Any, ...]) -> bytes:
        return ENCODERS[encode][1](*args)


PROFILES: dict[str, type[Recording]] = {"foxglove": Recording, "ros2": Ros2Recording}


def read_messages(path: Path) -> Iterator[tuple[Any, Any, Any]]:
    """(schema, channel, message) of every message in an MCAP file, also one whose writer was
    killed (no summary, a torn last record): read front to back, up to the first torn record."""
    from drivers.replay import mcap_messages

    with open(path, "rb") as f:
        yield from mcap_messages(f)
