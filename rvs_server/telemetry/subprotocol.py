"""The Foxglove port, in front of foxglove-sdk's server: the SDK accepts a WebSocket only under
the subprotocol name ``foxglove.sdk.v1`` and answers 400 to ``foxglove.websocket.v1``, the
name the same protocol had before (and still has in the official client library,
``@foxglove/ws-protocol``, and the apps built on it, such as Lichtblick). No SDK option names
another, so this relay takes the connection, renames an offer of the old name alone to the new
one for the SDK, and the SDK's answer back to the name the client offered; from then on it
copies bytes both ways, unread. A client offering the new name goes through unchanged.

It runs in the telemetry process (threads of its own beside the SDK's); the SDK listens on
loopback, on a port of its own choosing.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading

SDK_NAME = "foxglove.sdk.v1"
OLD_NAME = "foxglove.websocket.v1"  # the same protocol, as foxglove.websocket's clients name it
HEADER = b"sec-websocket-protocol:"
CHUNK = 4 * 1024 * 1024  # read and written at once: a map layer in a few copies, not hundreds


def renamed_offer(head: bytes) -> tuple[bytes, bool]:
    """The request's head with an offer of :data:`OLD_NAME` (without :data:`SDK_NAME`) made
    one of :data:`SDK_NAME`; whether it was renamed."""
    lines = head.split(b"\r\n")
    for i, line in enumerate(lines):
        if line.lower().startswith(HEADER):
            offered = [p.strip() for p in line[len(HEADER):].decode("latin-1").split(",")]
            if SDK_NAME in offered or OLD_NAME not in offered:
                return head, False
            lines[i] = b"Sec-WebSocket-Protocol: " + ", ".join(
                SDK_NAME if p == OLD_NAME else p for p in offered).encode("latin-1")
            return b"\r\n".join(lines), True
    return head, False


def renamed_answer(head: bytes) -> bytes:
    """The SDK's handshake answer with the subprotocol it chose named as the client offered it."""
    lines = head.split(b"\r\n")
    for i, line in enumerate(lines):
        if line.lower().startswith(HEADER) and line[len(HEADER):].strip().decode("latin-1") == SDK_NAME:
            lines[i] = b"Sec-WebSocket-Protocol: " + OLD_NAME.encode()
    return b"\r\n".join(lines)


class SubprotocolRelay:
    """Listens on ``host:port`` (RuntimeError if it cannot bind) and relays each connection to
    the SDK's server on ``127.0.0.1:sdk_port``, renaming the subprotocol in the handshake."""

    def __init__(self, host: str, port: int) -> None:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        try:
            self._sock = socket.create_server((host, port), family=family, backlog=64)
        except OSError as exc:
            raise RuntimeError(str(exc)) from None
        self.port: int = self._sock.getsockname()[1]
        self.sdk_port = 0  # set by start(), once the SDK listens
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="rvs-foxglove-relay", daemon=True)

    def start(self, sdk_port: int) -> None:
        self.sdk_port = sdk_port
        self._thread.start()
        asyncio.run_coroutine_threadsafe(asyncio.start_server(self._serve, sock=self._sock, limit=CHUNK), self._loop).result(10)

    def close(self) -> None:
        if self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(5.0)
        self._sock.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        up_writer: asyncio.StreamWriter | None = None
        try:
            head = await reader.readuntil(b"\r\n\r\n")  # up to the reader's limit, 64 KiB
            head, renamed = renamed_offer(head)
            up_reader, up_writer = await asyncio.open_connection("127.0.0.1", self.sdk_port, limit=CHUNK)
            up_writer.write(head)
            answer = await up_reader.readuntil(b"\r\n\r\n")
            writer.write(renamed_answer(answer) if renamed else answer)
            await asyncio.gather(_copy(reader, up_writer), _copy(up_reader, writer))
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError):
            pass  # a client or the SDK went away: the other side is closed below
        finally:
            for w in (writer, up_writer):
                if w is not None:
                    w.close()


async def _copy(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    """Bytes as they come until EOF, then the write side closed (the other direction ends too)."""
    try:
        while data := await reader.read(CHUNK):
            writer.write(data)
            await writer.drain()
    finally:
        with contextlib.suppress(OSError):
            writer.close()
