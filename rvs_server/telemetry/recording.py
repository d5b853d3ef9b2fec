"""An MCAP recording: the live channels, plus each device's raw frames in full resolution and
every wire line with its time, written through foxglove-sdk's MCAP writer.

The file is written in place (not to a temporary name renamed at the end) because a recording
must be readable after the server is killed: messages go into zstd-compressed chunks, and a
chunk that is finished is on disk for good. The hub finishes the open chunk at least every
:data:`FLUSH_S`, so a SIGKILL loses the messages of the last second or so, plus the summary
(the index and statistics at the end): an MCAP reader then reads the file front to back, as
``mcap recover`` or :func:`read_messages` here do.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import foxglove
from foxglove.mcap import MCAPCompression, MCAPWriteOptions

from .outlet import Outlet

if TYPE_CHECKING:
    from .hub import Telemetry

FLUSH_S = 1.0  # the longest a message waits in the open chunk (what a SIGKILL loses at most)
CHUNK_BYTES = 4 * 1024 * 1024  # a chunk is also finished at this uncompressed size


class Recording(Outlet):
    def __init__(self, hub: Telemetry, path: Path, metadata: dict[str, str]) -> None:
        super().__init__(live=False)
        self.declare()
        self.path = path
        self.started = time.monotonic()
        self.writer = foxglove.open_mcap(path, context=self.context, writer_options=MCAPWriteOptions(
            compression=MCAPCompression.Zstd, chunk_size=CHUNK_BYTES, compression_threads=0))
        self.writer.write_metadata("rvs", metadata)
        self._flushed = time.monotonic()
        self._flush_lock = threading.Lock()
        self._hub = hub
        hub.attach(self)

    def tick(self, now: float) -> None:
        if now - self._flushed >= FLUSH_S:
            self._flushed = now
            with self._flush_lock:
                self.writer.flush()

    def close(self) -> dict[str, Any]:
        """Stop, write the summary; what the file holds (blocking: run it off the event loop)."""
        self._hub.detach(self).wait(5.0)
        with self._flush_lock:
            self.writer.close()
        return {"messages": sum(self.counts.values()), "seconds": time.monotonic() - self.started,
                "bytes": self.path.stat().st_size}


def read_messages(path: Path) -> Iterator[tuple[Any, Any, Any]]:
    """(schema, channel, message) of every message in an MCAP file, also one whose writer was
    killed (no summary, a torn last record): read front to back, up to the first torn record."""
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader

    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False, emit_chunks=False).records:
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Message):
                    channel = channels[record.channel_id]
                    yield schemas.get(channel.schema_id), channel, record
        except Exception:  # noqa: BLE001 - a torn tail fails in the record parser or the decompressor alike
            return
