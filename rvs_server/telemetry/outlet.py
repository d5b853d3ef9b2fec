"""Where encoded messages go, in the telemetry process: one Foxglove context per destination
(the live server, a recording), each with its own channels, so a message is encoded once and
logged to each destination that wants it, and what only one of them needs (a map again for a
client that just subscribed, the current state at a recording's start) goes to that one alone.

The topic table is the one declaration of every channel: its schema, whether the live server
carries it (the raw frames and the wire's JSON copy are for recordings only) and whether it is
latched; the server's hub reads it too, to send only what a destination wants.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import foxglove
from foxglove.messages import (
    CompressedImage,
    FrameTransforms,
    Grid,
    Log,
    PointCloud,
    PoseInFrame,
    RawImage,
    SceneUpdate,
)

from drivers.hazcam import CAMERAS as HAZCAMS
from prox_workflows.layers import LAYERS


@dataclass(frozen=True)
class Topic:
    schema: Any  # a foxglove Schema (protobuf) or a JSON schema (dict)
    live: bool = True  # the Foxglove server carries it (else recordings only)
    latched: bool = False  # its last message is sent again to whoever starts listening


JOB_SCHEMA = {"type": "object", "title": "rvs.JobProgress", "properties": {
    "job": {"type": "integer"}, "command": {"type": "string"}, "status": {"type": "string"},
    "phase": {"type": "string"}, "done": {"type": "integer"}, "total": {"type": "integer"},
    "fraction": {"type": "number"}, "message": {"type": "string"}}}
WIRE_SCHEMA = {"type": "object", "title": "rvs.WireLine", "properties": {
    "dir": {"type": "string", "enum": ["request", "reply", "event"]}, "conn": {"type": ["integer", "null"]},
    "line": {"type": "string"}}}

CALL_SCHEMA = {"type": "object", "title": "rvs.DeviceCall", "properties": {
    "device": {"type": "string"}, "call": {"type": "string"}, "args": {"type": "array"}, "result": {},
    "ptu": {"type": ["array", "null"]}, "pose": {"type": "array"}}}

TOPICS: dict[str, Topic] = {
    "/tf": Topic(FrameTransforms.get_schema()),
    "/rover/pose": Topic(PoseInFrame.get_schema()),
    "/rover/truth": Topic(PoseInFrame.get_schema()),
    "/tof/points": Topic(PointCloud.get_schema()),
    "/tof/depth": Topic(RawImage.get_schema()),
    "/tof/amplitude": Topic(RawImage.get_schema()),
    "/tof/distance": Topic(RawImage.get_schema()),
    "/tof/confidence": Topic(RawImage.get_schema()),
    "/stereo/left/compressed": Topic(CompressedImage.get_schema()),
    "/stereo/right/compressed": Topic(CompressedImage.get_schema()),
    **{f"/hazcam/{pair}/left/compressed": Topic(CompressedImage.get_schema()) for pair in HAZCAMS},
    **{f"/hazcam/{pair}/points": Topic(PointCloud.get_schema()) for pair in HAZCAMS},
    "/nav/bounds": Topic(Grid.get_schema(), latched=True),
    "/nav/plan": Topic(SceneUpdate.get_schema(), latched=True),
    "/nav/track": Topic(SceneUpdate.get_schema(), latched=True),
    "/nav/check_move": Topic(SceneUpdate.get_schema(), latched=True),
    "/rvs/log": Topic(Log.get_schema()),
    "/rvs/job": Topic(JOB_SCHEMA),
    "/rvs/wire": Topic(WIRE_SCHEMA, live=False),
    "/raw/calls": Topic(CALL_SCHEMA, live=False),
    "/raw/tof/xyz": Topic(RawImage.get_schema(), live=False),
    "/raw/tof/amplitude": Topic(RawImage.get_schema(), live=False),
    "/raw/tof/image": Topic(RawImage.get_schema(), live=False),
    "/raw/stereo/left": Topic(RawImage.get_schema(), live=False),
    "/raw/stereo/right": Topic(RawImage.get_schema(), live=False),
    **{f"/raw/hazcam/{pair}/{side}": Topic(RawImage.get_schema(), live=False)
       for pair in HAZCAMS for side in ("left", "right")},
}
MAP_PREFIX = "/map/"  # + layer name: one Grid channel per layer, latched
MAP_TOPIC = Topic(Grid.get_schema(), latched=True)


def topic_spec(topic: str) -> Topic:
    return MAP_TOPIC if topic.startswith(MAP_PREFIX) else TOPICS[topic]


class Outlet:
    """One destination's context and channels (created on first use); counts what it logged.
    ``profile`` names how it encodes a message: Foxglove's schemas here, ROS 2's in a
    recording of the ``ros2`` profile (:class:`.recording.Ros2Recording`)."""

    profile = "foxglove"

    def __init__(self, live: bool) -> None:
        self.live = live
        self.context = foxglove.Context()
        self.counts: Counter[str] = Counter()
        self._channels: dict[str, foxglove.Channel] = {}

    def channel(self, topic: str, encode: Callable[..., bytes] | None = None) -> foxglove.Channel | None:
        """The topic's channel here, or None when this destination does not carry it; ``encode``
        (the function of :mod:`.messages` its messages come from) for a destination whose
        schema depends on it."""
        ch = self._channels.get(topic)
        if ch is None:
            spec = topic_spec(topic)
            if self.live and not spec.live:
                return None
            ch = self._channels[topic] = self.open_channel(topic, spec, encode)
        return ch

    def open_channel(self, topic: str, spec: Topic, encode: Callable[..., bytes] | None) -> foxglove.Channel:
        encoding = "json" if isinstance(spec.schema, dict) else "protobuf"
        return foxglove.Channel(topic, schema=spec.schema, message_encoding=encoding, context=self.context)

    def encode(self, encode: Callable[..., bytes], args: tuple[Any, ...]) -> bytes:
        """A message as this destination logs it: ``encode(*args)``, a function of :mod:`.messages`."""
        return encode(*args)

    def declare(self) -> None:
        """Open every topic's channel at once (a map layer's of every registered layer): a
        recording lists them all, its statistics saying which carried messages."""
        for topic in [*TOPICS, *(MAP_PREFIX + name for name in LAYERS)]:
            self.channel(topic)

    def wants(self, topic: str, encode: Callable[..., bytes] | None = None) -> bool:
        ch = self.channel(topic, encode)
        return ch is not None and ch.base.has_sinks()

    def log(self, topic: str, data: bytes, t_ns: int) -> None:
        ch = self.channel(topic)
        if ch is not None:
            ch.log(data, log_time=t_ns)
            self.counts[topic] += 1

    def listened(self) -> frozenset[str]:
        """The topics whose channel has a sink here (a subscribed client, the MCAP writer)."""
        return frozenset(topic for topic, ch in self._channels.items() if ch.base.has_sinks())
