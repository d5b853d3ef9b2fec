"""The telemetry process: foxglove-sdk's WebSocket server and the MCAP recording, fed by the
server's hub over a pipe (:mod:`.link`, which starts it). Each message arrives as a function of
:mod:`.messages` and its arguments and is encoded here once, for every destination that wants
it; the SDK's calls hold this process's GIL, not the server's.

It keeps the last message of every latched topic (maps, plan, track, check-move) and sends it
to a client that subscribes later and to a recording at its start, without asking the server.

It exits when its input pipe closes or its parent is gone: the server stopped, or was killed.
A recording in progress is finished first (its summary written), so a SIGKILL of the server
costs the file nothing.

    python -m rvs_server.telemetry.worker IN_FD OUT_FD HOST PORT NAME
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path
from queue import Empty, SimpleQueue
from typing import Any

from .link import read, write
from .live import LiveOutlet
from .outlet import Outlet, topic_spec
from .recording import PROFILES, Recording

TICK = 0.1  # s between looks at subscriptions, the recording's flush and the parent
NICE = 10  # on a busy machine the server's event loop and jobs get the CPU first; the queue waits


class Worker:
    def __init__(self, out: Connection, host: str, port: int, name: str) -> None:
        self.out = out
        self.live: LiveOutlet | None = None
        self.live_off: str | None = "server.foxglove_port is 0"
        self.recording: Recording | None = None
        self._latched: dict[str, list[Any]] = {}  # topic -> [t_ns, encode, args, its bytes by profile once encoded]
        self._subscribed: SimpleQueue[str] = SimpleQueue()  # filled in the SDK's threads
        self._listened: frozenset[str] = frozenset()
        if port:
            try:
                self.live = LiveOutlet(host, port, name, self._subscribed.put)
                self.live_off = None
            except RuntimeError as exc:
                self.live_off = f"Foxglove port {host}:{port} could not be served ({exc})"

    def outlets(self) -> tuple[Outlet, ...]:
        return tuple(o for o in (self.live, self.recording) if o is not None)

    def send(self, *message: Any) -> None:
        """To the server; a server that is gone is not told."""
        try:
            write(self.out, message)
        except OSError:
            pass

    def handle(self, entry: tuple[Any, ...]) -> bool:
        """One entry from the server; False when told to close."""
        if entry[0] == "log":
            _, topic, t_ns, encode, args = entry
            try:
                self._log(topic, t_ns, encode, args)
            except Exception as exc:  # noqa: BLE001 - a bad message costs only itself
                self.send("error", topic, f"{type(exc).__name__}: {exc}")
            return True
        if entry[0] == "offer":
            if self.live is not None:
                self.live.channel(entry[1])  # advertised to every client from now on
            return True
        _, call_id, op, args = entry
        try:
            result = getattr(self, f"call_{op}")(*args)
        except Exception as exc:  # noqa: BLE001 - the server says why to whoever asked
            self.send("reply", call_id, False, f"{type(exc).__name__}: {exc}")
        else:
            self.send("reply", call_id, True, result)
        return op != "close"

    def _log(self, topic: str, t_ns: int, encode: Callable[..., bytes], args: tuple[Any, ...],
             outlets: tuple[Outlet, ...] | None = None) -> None:
        latched = topic_spec(topic).latched
        if latched and outlets is None:
            self._latched[topic] = [t_ns, encode, args, {}]
        wanting = [o for o in (self.outlets() if outlets is None else outlets) if o.wants(topic, encode)]
        # each profile's bytes once, for every destination of that profile; a latched topic's kept
        encoded: dict[str, bytes] = self._latched[topic][3] if latched else {}
        for outlet in wanting:
            data = encoded.get(outlet.profile)
            if data is None:
                data = encoded[outlet.profile] = outlet.encode(encode, args)
            outlet.log(topic, data, t_ns)

    def _send_latched(self, outlet: Outlet, topic: str | None = None) -> None:
        for key, (t_ns, encode, args, _) in list(self._latched.items()):
            if topic in (None, key):
                self._log(key, t_ns, encode, args, (outlet,))

    def tick(self) -> None:
        """Latched messages to the topics just subscribed, the server told what is listened to,
        the recording's open chunk finished when it is due."""
        while True:
            try:
                topic = self._subscribed.get_nowait()
            except Empty:
                break
            if self.live is not None:
                self._send_latched(self.live, topic)
        if self.live is not None:
            listened = self.live.listened()
            if listened != self._listened:
                self._listened = listened
                self.send("subscribed", listened)
        if self.recording is not None:
            self.recording.tick(time.monotonic())

    # -- calls from the server

    def call_record_start(self, path: Path, metadata: dict[str, str], profile: str) -> None:
        if self.recording is not None:
            raise RuntimeError(f"already recording to {self.recording.path}")
        self.recording = PROFILES[profile](path, metadata)
        self._send_latched(self.recording)  # the recording stands alone

    def call_record_stop(self) -> dict[str, Any]:
        recording, self.recording = self.recording, None
        if recording is None:
            raise RuntimeError("not recording")
        return recording.close()

    def call_close(self) -> None:
        if self.recording is not None:
            self.call_record_stop()
        if self.live is not None:
            self.live.close()
            self.live = None


def main(argv: list[str]) -> None:
    in_fd, out_fd, host, port, name = argv
    os.nice(NICE)
    source = Connection(int(in_fd), writable=False)
    parent = os.getppid()
    worker = Worker(Connection(int(out_fd), readable=False), host, int(port), name)
    worker.send("started", worker.live.url if worker.live is not None else None, worker.live_off)
    try:
        running = True
        while running and os.getppid() == parent:
            if source.poll(TICK):
                try:
                    batch = read(source)
                except EOFError:  # the server stopped or died
                    break
                for entry in batch:
                    running = worker.handle(entry) and running
            worker.tick()
    finally:
        worker.call_close()
    # The recording is finished and Foxglove's server stopped: the interpreter's teardown would
    # only free memory, which this niced process takes seconds for on a busy machine while the
    # server's shutdown waits for it to exit.
    sys.stdout.flush()
    os._exit(0)


if __name__ == "__main__":
    main(sys.argv[1:])
