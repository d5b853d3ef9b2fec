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

import os
import time
from collections import Counter
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import foxglove
import yaml
from foxglove.mcap import MCAPCompression, MCAPWriteOptions

from .outlet import Outlet, Topic, topic_spec
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
        super().log(topic, data, self.log_time(t_ns))

    def log_time(self, t_ns: int) -> int:
        """The log time of a message stamped ``t_ns``: one from before the start (what is
        latched, sent again to the new file: a map, the plan; one under way as the recording
        started) is logged at the start, so that the file's time range is the recording's; its
        content keeps its own time."""
        return max(t_ns, self.start_ns)

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
    channel's schema the type's full definition (:mod:`.ros2_msgs`), in a rosbag2 directory:
    ``<name>/<name>_0.mcap`` and the ``metadata.yaml`` rosbag2 opens a bag by (topics, types,
    offered QoS: transient_local for the latched topics, so ``ros2 bag play`` latches the maps
    with no overrides). The metadata is rewritten whenever a topic appears and at every flush
    (atomically), so a bag whose writer was killed opens with what its file holds, and finally
    with the counts on close. A channel is made with its first message, whose encoding gives
    its type; the rest is as :class:`Recording`."""

    profile = "ros2"
    mcap_profile = "ros2"

    def __init__(self, path: Path, metadata: dict[str, str]) -> None:
        self.types: dict[str, str] = {}  # topic -> ROS 2 type, in the order the channels opened
        self.first_ns: int | None = None
        self.last_ns = 0
        super().__init__(path, metadata)
        self.write_metadata()

    def declare(self) -> None:
        """Nothing ahead: a topic's ROS 2 type is known from its first message."""

    def open_channel(self, topic: str, spec: Topic, encode: Callable[..., bytes] | None) -> foxglove.Channel:
        if encode is None:
            raise KeyError(f"{topic}: a ROS 2 channel is opened by its first message")
        short = ENCODERS[encode][0]
        schema = foxglove.Schema(name=type_name(short), encoding=SCHEMA_ENCODING, data=definition(short).encode())
        # rosbag2's MCAP storage keeps each topic's offered QoS in its channel's metadata too, and
        # a reader matches the channel to metadata.yaml's topic by it
        channel = foxglove.Channel(topic, schema=schema, message_encoding=MESSAGE_ENCODING, context=self.context,
                                   metadata={"offered_qos_profiles": offered_qos(spec.latched)})
        self.types[topic] = type_name(short)
        return channel

    def encode(self, encode: Callable[..., bytes], args: tuple[Any, ...]) -> bytes:
        return ENCODERS[encode][1](*args)

    def log(self, topic: str, data: bytes, t_ns: int) -> None:
        known = len(self.types)
        super().log(topic, data, t_ns)
        t_ns = self.log_time(t_ns)  # the metadata's time range is the file's
        self.first_ns = t_ns if self.first_ns is None else min(self.first_ns, t_ns)
        self.last_ns = max(self.last_ns, t_ns)
        if len(self.types) != known:
            self.write_metadata()

    def tick(self, now: float) -> None:
        if now - self._flushed >= FLUSH_S:
            super().tick(now)
            self.write_metadata()

    def close(self) -> dict[str, Any]:
        out = super().close()
        self.write_metadata()
        return {**out, "bytes": out["bytes"] + (self.path.parent / "metadata.yaml").stat().st_size}

    def write_metadata(self) -> None:
        """The bag's metadata.yaml, written to a temporary name and renamed over the old."""
        target = self.path.parent / "metadata.yaml"
        tmp = target.with_name(".metadata.yaml.tmp")
        tmp.write_text(yaml.safe_dump(bag_metadata(self.path.name, self.types, self.counts, self.first_ns,
                                                   self.last_ns), sort_keys=False), "utf-8")
        os.replace(tmp, target)


# rosbag2's metadata.yaml as Jazzy writes it for MCAP storage (format version 8: each topic's
# offered QoS profiles a YAML string; rmw's enums: history 1 keep_last, reliability 1 reliable,
# durability 1 transient_local / 2 volatile, liveliness 1 automatic; an unset duration is rmw's
# infinite, 9223372036 s 854775807 ns)
BAG_VERSION = 8


def _infinite() -> dict[str, int]:
    return {"sec": 9223372036, "nsec": 854775807}  # a dict each: YAML would write a shared one as an alias


def offered_qos(latched: bool) -> str:
    """A topic's offered QoS as rosbag2 records it: a YAML list of one publisher's profile."""
    profile = {"history": 1, "depth": 1 if latched else 10, "reliability": 1, "durability": 1 if latched else 2,
               "deadline": _infinite(), "lifespan": _infinite(), "liveliness": 1,
               "liveliness_lease_duration": _infinite(), "avoid_ros_namespace_conventions": False}
    return yaml.safe_dump([profile], sort_keys=False).strip()


def bag_metadata(file: str, types: dict[str, str], counts: Counter[str] | dict[str, int], first_ns: int | None,
                 last_ns: int) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of a bag of one MCAP ``file``."""
    total = sum(counts.get(t, 0) for t in types)
    start = first_ns if first_ns is not None else 0
    duration = max(0, last_ns - start) if first_ns is not None else 0
    topics = [{"topic_metadata": {"name": topic, "type": msgtype, "serialization_format": MESSAGE_ENCODING,
                                  "offered_qos_profiles": offered_qos(topic_spec(topic).latched),
                                  "type_description_hash": ""},
               "message_count": counts.get(topic, 0)} for topic, msgtype in types.items()]
    return {"rosbag2_bagfile_information": {
        "version": BAG_VERSION, "storage_identifier": "mcap", "relative_file_paths": [file],
        "duration": {"nanoseconds": duration}, "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": total, "topics_with_message_count": topics,
        "compression_format": "", "compression_mode": "",
        "files": [{"path": file, "starting_time": {"nanoseconds_since_epoch": start},
                   "duration": {"nanoseconds": duration}, "message_count": total}],
        "custom_data": {}, "ros_distro": "",
    }}


PROFILES: dict[str, type[Recording]] = {"foxglove": Recording, "ros2": Ros2Recording}


def read_messages(path: Path) -> Iterator[tuple[Any, Any, Any]]:
    """(schema, channel, message) of every message in an MCAP file, also one whose writer was
    killed (no summary, a torn last record): read front to back, up to the first torn record."""
    from drivers.replay import mcap_messages

    with open(path, "rb") as f:
        yield from mcap_messages(f)
