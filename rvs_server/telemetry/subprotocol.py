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

import contextlib
import os
import socket
import threading

SDK_NAME = "foxglove.sdk.v1"
OLD_NAME = "foxglove.websocket.v1"  # the same protocol, as foxglove.websocket's clients name it
HEADER = b"sec-websocket-protocol:"
CHUNK = 1024 * 1024  # moved per splice call at most
MAX_HEAD = 64 * 1024  # a handshake's head; more is no WebSocket client's


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
    the SDK's server on ``127.0.0.1:sdk_port``, renaming the subprotocol in the handshake. A
    thread per direction of each connection (Foxglove clients are a handful) moves the bytes
    with splice(2): kernel to kernel, never through Python objects or the GIL."""

    def __init__(self, host: str, port: int) -> None:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        try:
            self._sock = socket.create_server((host, port), family=family, backlog=64)
        except OSError as exc:
            raise RuntimeError(str(exc)) from None
        self.port: int = self._sock.getsockname()[1]
        self.sdk_port = 0  # set by start(), once the SDK listens
        self._open: set[socket.socket] = set()  # the relayed connections' sockets, shut at close
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._accept, name="rvs-foxglove-relay", daemon=True)

    def start(self, sdk_port: int) -> None:
        self.sdk_port = sdk_port
        self._thread.start()

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)  # wakes the accept
        self._sock.close()
        with self._lock:
            for sock in self._open:
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
        if self._thread.is_alive():
            self._thread.join(5.0)

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self._sock.accept()
            except OSError:  # closed
                return
            threading.Thread(target=self._serve, args=(client,), name="rvs-foxglove-relay", daemon=True).start()

    def _serve(self, client: socket.socket) -> None:
        upstream: socket.socket | None = None
        with self._lock:
            self._open.add(client)
        try:
            head, rest = _head(client)
            head, renamed = renamed_offer(head)
            upstream = socket.create_connection(("127.0.0.1", self.sdk_port))
            with self._lock:
                self._open.add(upstream)
            upstream.sendall(head + rest)
            answer, rest = _head(upstream)
            client.sendall((renamed_answer(answer) if renamed else answer) + rest)
            back = threading.Thread(target=_pump, args=(upstream, client), name="rvs-foxglove-relay", daemon=True)
            back.start()
            _pump(client, upstream)
            back.join()
        except OSError:
            pass  # a client or the SDK went away, or sent no handshake
        finally:
            with self._lock:
                self._open.discard(client)
                if upstream is not None:
                    self._open.discard(upstream)
            client.close()
            if upstream is not None:
                upstream.close()


def _head(sock: socket.socket) -> tuple[bytes, bytes]:
    """An HTTP head read from ``sock`` up to its blank line, and what came after it (the SDK may
    send its first frame in the same segment as its answer). OSError at EOF or past MAX_HEAD."""
    data = b""
    while b"\r\n\r\n" not in data:
        if len(data) > MAX_HEAD:
            raise OSError("handshake too long")
        chunk = sock.recv(4096)
        if not chunk:
            raise OSError("closed during the handshake")
        data += chunk
    end = data.index(b"\r\n\r\n") + 4
    return data[:end], data[end:]


def _pump(src: socket.socket, dst: socket.socket) -> None:
    """Move bytes from ``src`` to ``dst`` until EOF or an error, then end both directions of the
    pair (the other pump stops too)."""
    r, w = os.pipe()
    try:
        while n := os.splice(src.fileno(), w, CHUNK):
            while n:
                n -= os.splice(r, dst.fileno(), n)
    except OSError:
        pass
    finally:
        os.close(r)
        os.close(w)
        for sock in (src, dst):
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
