"""The server's end of the telemetry process (:mod:`.worker`), where foxglove-sdk's WebSocket
server and MCAP writer run and every Foxglove message is encoded. They are not in the server's
process because the SDK holds the GIL for the whole of a call (a ``log()`` copies, compresses
and writes; an ``encode()`` copies): a map layer of 1717 x 1695 cells costs tens of
milliseconds, which the event loop would wait for.

The process is started by exec (a subprocess, never a fork of this threaded server) and talks
over two pipes: messages and calls go to it, its start, subscriptions and replies come back.
What goes to it is queued here and written by a sender thread, each message as the function of
:mod:`.messages` that encodes it and its arguments; arrays go as they are (pickle protocol 5,
out of band), so the server copies nothing and the write syscalls release the GIL.

The queue is bounded, and no thread of the server ever waits for the process: when it falls
behind, what only the live view wants is dropped first (``live_dropped``, from
:data:`LIVE_BYTES` queued), what a recording or a latched topic needs only when the queue is
full (``dropped``, at :data:`QUEUE_BYTES`).

The process exits when its pipe closes: the server stopped, or died (a recording is finished
first); see :mod:`.worker`.
"""

from __future__ import annotations

import fcntl
import itertools
import os
import pickle
import subprocess
import sys
import threading
from collections import Counter, deque
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np
import structlog

from .outlet import topic_spec

log = structlog.get_logger("rvs.telemetry")

QUEUE_BYTES = 512 * 1024 * 1024  # at most this much waits for the process (a few large maps)
LIVE_BYTES = 64 * 1024 * 1024  # a message only the live view wants is dropped once this much waits
START_S = 60.0  # for the process to import and bind the Foxglove port (a loaded machine is slow at imports)
CALL_S = 120.0  # for a call's answer (it comes after whatever was queued before it)
PIPE_BYTES = 1024 * 1024  # the pipe's buffer, if the system allows: a map layer in a dozen writes
ROOT = Path(__file__).resolve().parents[2]  # where this rvs_server is: the process runs the same code


class TelemetryError(RuntimeError):
    """The telemetry process could not do what was asked (or is gone); the message says why."""


def write(conn: Connection, obj: Any) -> None:
    """Send ``obj`` with its arrays' buffers apart: one frame for the pickle, one per buffer."""
    buffers: list[pickle.PickleBuffer] = []
    head = pickle.dumps(obj, protocol=5, buffer_callback=buffers.append)
    conn.send_bytes(len(buffers).to_bytes(4, "little") + head)
    for buf in buffers:
        conn.send_bytes(buf.raw())


def read(conn: Connection) -> Any:
    """What :func:`write` sent; EOFError once the other end is closed."""
    head = conn.recv_bytes()
    buffers = [conn.recv_bytes() for _ in range(int.from_bytes(head[:4], "little"))]
    return pickle.loads(memoryview(head)[4:], buffers=buffers)


def _size(args: tuple[Any, ...]) -> int:
    return 256 + sum(a.nbytes for a in args if isinstance(a, np.ndarray))


class Link:
    """The telemetry process seen from the server. Constructing it starts the process and waits
    for its start (blocking: run it off the event loop); ``url`` is then the Foxglove server's
    or None, and ``live_off`` why there is none. Thread-safe."""

    def __init__(self, host: str, port: int, name: str) -> None:
        to_r, to_w = os.pipe()
        from_r, from_w = os.pipe()
        try:
            fcntl.fcntl(to_w, fcntl.F_SETPIPE_SZ, PIPE_BYTES)
        except OSError:  # above the system's pipe-max-size: the default buffer works, in more writes
            pass
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, (str(ROOT), os.environ.get("PYTHONPATH"))))}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "rvs_server.telemetry.worker", str(to_r), str(from_w), host, str(port), name],
            pass_fds=(to_r, from_w), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, env=env,
            start_new_session=True)  # a Ctrl-C or a service's SIGTERM reaches the server, which stops it in order
        os.close(to_r)
        os.close(from_w)
        self._out = Connection(to_w, readable=False)
        self._in = Connection(from_r, writable=False)
        self.subscribed: frozenset[str] = frozenset()  # live topics a Foxglove client listens to
        self.on_subscribed: Callable[[frozenset[str]], None] | None = None  # told the topics newly listened to
        self.recording = False
        self.exited: str | None = None  # why the process is gone, once it is
        self.live_dropped = 0
        self.dropped = 0
        self.logged: Counter[str] = Counter()  # messages handed to the process, by topic
        self._offered: set[str] = set()  # live topics the process was told exist (offer)
        self._queue: deque[tuple[Any, int]] = deque()
        self._queued = 0  # bytes in the queue
        self._wake = threading.Condition()
        self._calls: dict[int, list[Any]] = {}  # call id -> [event, ok, result]
        self._ids = itertools.count(1)
        try:
            if not self._in.poll(START_S):
                raise TelemetryError(f"the telemetry process did not start in {START_S:g} s")
            _, self.url, self.live_off = read(self._in)
        except (EOFError, TelemetryError) as exc:
            self.proc.kill()
            code = self.proc.wait()
            self._out.close()
            self._in.close()
            raise TelemetryError(str(exc) if isinstance(exc, TelemetryError)
                                 else f"the telemetry process exited at its start (code {code})") from None
        self._sender = threading.Thread(target=self._send_loop, name="rvs-telemetry-send", daemon=True)
        self._reader = threading.Thread(target=self._read_loop, name="rvs-telemetry-read", daemon=True)
        self._sender.start()
        self._reader.start()

    @property
    def live(self) -> bool:
        return self.url is not None and self.exited is None

    def wants(self, topic: str) -> bool:
        """Whether a message on ``topic`` goes anywhere: the recording takes every topic, a live
        one goes when a client listens. A latched topic nobody wants stays with the hub until
        someone does (:attr:`on_subscribed`): a map is a hundred megabytes of pipe."""
        if self.exited is not None:
            return False
        return self.recording or topic in self.subscribed

    def wants_any(self) -> bool:
        return self.exited is None and (self.recording or bool(self.subscribed))

    def log(self, topic: str, t_ns: int, encode: Any, *args: Any) -> None:
        """Queue a message: ``encode(*args)`` (a function of :mod:`.messages`) runs in the
        process. Never waits: past the queue's bounds the message is dropped and counted."""
        size = _size(args)
        keep = self.recording or topic_spec(topic).latched  # the process keeps it for later listeners
        with self._wake:
            if self._queued + size > (QUEUE_BYTES if keep else LIVE_BYTES):
                if keep:
                    self.dropped += 1
                else:
                    self.live_dropped += 1
                return
            self._queue.append((("log", topic, t_ns, encode, args), size))
            self._queued += size
            self.logged[topic] += 1
            self._wake.notify()

    def offer(self, topic: str) -> None:
        """``topic`` has something to say, though nobody listens: the live server advertises it
        from now on (once), so a client can subscribe. Never waits."""
        if topic in self._offered or self.url is None or not topic_spec(topic).live:
            return
        with self._wake:
            self._offered.add(topic)
            self._queue.append((("offer", topic), 0))
            self._wake.notify()

    def call(self, op: str, *args: Any, timeout: float = CALL_S) -> Any:
        """Ask the process to do ``op`` (after what is queued) and wait for its answer (blocking).
        Raises TelemetryError with the process's reason."""
        if self.exited is not None:
            raise TelemetryError(self.exited)
        call_id = next(self._ids)
        slot: list[Any] = [threading.Event(), False, None]
        self._calls[call_id] = slot
        with self._wake:
            self._queue.append((("call", call_id, op, args), 0))
            self._wake.notify()
        try:
            if not slot[0].wait(timeout):
                raise TelemetryError(f"the telemetry process did not answer {op} in {timeout:g} s")
        finally:
            self._calls.pop(call_id, None)
        if not slot[1]:
            raise TelemetryError(slot[2])
        return slot[2]

    def close(self, timeout: float = 30.0) -> None:
        """Stop the process (what is queued is done first, a recording finished) and wait for it."""
        if self.exited is None:
            try:
                self.call("close", timeout=timeout)
            except TelemetryError as exc:
                log.warning("telemetry_close_failed", reason=str(exc))
        with self._wake:
            self._queue.append((None, 0))
            self._wake.notify()
        self._sender.join(timeout)
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._reader.join(timeout)

    # ------------------------------------------------------------------ the threads

    def _send_loop(self) -> None:
        """Write what is queued, all of it in one frame (an array two messages share, as a ToF
        frame's points and raw image do, goes once); blocks in the write, never holding the GIL."""
        while True:
            with self._wake:
                while not self._queue:
                    self._wake.wait()
                batch = list(self._queue)
                self._queue.clear()
                queued = sum(size for _, size in batch)
            stop = any(entry is None for entry, _ in batch)
            entries = [entry for entry, _ in batch if entry is not None]
            try:
                if entries:
                    self._write(entries)
            except OSError:  # the process is gone: the reader says why
                stop = True
            with self._wake:
                self._queued -= queued
            if stop:
                self._out.close()
                return

    def _write(self, entries: list[Any]) -> None:
        try:
            write(self._out, entries)
        except (pickle.PicklingError, TypeError, AttributeError):  # an argument that does not pickle costs its message
            for entry in entries:
                try:
                    write(self._out, [entry])
                except (pickle.PicklingError, TypeError, AttributeError) as exc:
                    self.dropped += 1
                    log.error("telemetry_item_failed", topic=entry[1], error=f"{type(exc).__name__}: {exc}")

    def _read_loop(self) -> None:
        while True:
            try:
                what, *rest = read(self._in)
            except (EOFError, OSError):
                break
            if what == "subscribed":
                added = rest[0] - self.subscribed
                self.subscribed = rest[0]
                if added and self.on_subscribed is not None:
                    self.on_subscribed(added)
            elif what == "reply":
                call_id, ok, result = rest
                slot = self._calls.get(call_id)
                if slot is not None:
                    slot[1], slot[2] = ok, result
                    slot[0].set()
            elif what == "error":
                log.error("telemetry_item_failed", topic=rest[0], error=rest[1])
        self._in.close()
        try:
            code = self.proc.wait(5.0)
        except subprocess.TimeoutExpired:
            code = None
        self.exited = f"the telemetry process exited (code {code})"
        self.subscribed = frozenset()
        for slot in list(self._calls.values()):
            slot[1], slot[2] = False, self.exited
            slot[0].set()
        with self._wake:  # the sender stops too
            self._queue.append((None, 0))
            self._wake.notify()

