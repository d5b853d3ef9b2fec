"""The asyncio TCP server: connections, their line handling and output, graceful shutdown.

Connections are asyncio Protocols rather than streams: lines are split and dispatched straight
from ``data_received`` (no task per line), and output goes to the transport's buffer, so a slow
reader only ever costs its own buffer, never the other clients' latency.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import os
import signal
import socket
import threading
import time
from collections import deque
from typing import Any

import structlog

from .app import App
from .heap import give_back_memory
from .protocol import (
    INTERRUPT,
    TIMING_MARK,
    WILL_TIMING_MARK,
    LineSplitter,
    Reply,
    Telnet,
    TooLong,
    format_reply,
    format_reply_json,
)
from .telemetry import Station
from .web.address import console_host

log = structlog.get_logger("rvs.server")

MAX_PENDING_LINES = 256  # stop reading from a client that is this far ahead of us
LINES_PER_TURN = 64  # lines of one connection handled before the event loop serves the others
MAX_OUTPUT_BYTES = 8 * 1024 * 1024  # a client that reads nothing is dropped past this


class Connection(asyncio.Protocol):
    observes_jobs = False  # a TCP client gets the lines of its own jobs only

    def __init__(self, app: App) -> None:
        self.app = app
        self.id = app.new_connection_id()
        self.transport: asyncio.Transport | None = None
        self.splitter = LineSplitter(app.server_cfg.max_line)
        self.pending: deque[bytes | TooLong | Telnet] = deque()
        self.waiting: asyncio.Future[Any] | None = None
        self.events = True
        self.json = False
        self.authenticated = False
        self.closed = False
        self.paused = False
        self.peer = "?"
        self.address = "?"  # the client's IP address: wrong tokens are counted by it (commands/system.py)
        self.log = log
        self.jobs_running = 0  # jobs this connection started: their final lines still owed
        self.exiting = False  # `exit` was answered: close once that reply is out, read nothing more
        self.jobs_started = 0  # until its first job, format json counts as said at connect time

    # ------------------------------------------------------------ asyncio.Protocol

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        sock = transport.get_extra_info("socket")
        if sock is not None and sock.family in (socket.AF_INET, socket.AF_INET6):
            # asyncio sets TCP_NODELAY only on sockets whose proto is IPPROTO_TCP, and those of
            # socket.create_server have proto 0: without this a reply written right after another
            # line (an EVENT, an ACK) waits for the client's delayed ACK, about 40 ms.
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            # telnet marks its interrupt with urgent data (IAC DM): read inline, the DM is
            # stripped with the other telnet commands instead of leaving a lone IAC behind
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_OOBINLINE, 1)
        peer = transport.get_extra_info("peername")
        self.peer = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer)
        self.address = str(peer[0]) if isinstance(peer, tuple) else str(peer)
        self.log = log.bind(conn=self.id, peer=self.peer)
        if len(self.app.connections) >= self.app.server_cfg.max_clients:
            self.send(Reply("RVS", "ERROR", {
                "code": "E_BUSY",
                "message": f"too many clients ({self.app.server_cfg.max_clients}); try again later",
            }))
            self.log.warning("client_refused", reason="max_clients")
            self.close()
            return
        self.app.connections.add(self)
        self.log.info("client_connected", clients=len(self.app.connections))
        self.greet()

    def greet(self) -> None:
        """The hello EVENT: at connect, and again in JSON when format json comes at connect time
        (a JSON-only client then has a greeting it can parse)."""
        self.send(self.app.hello())

    def data_received(self, data: bytes) -> None:
        if self.closed or self.exiting:
            return
        for item in self.splitter.feed(data):
            if item is INTERRUPT:
                self._interrupt()  # at once, ahead of lines still queued: it is an interrupt
            else:
                self.pending.append(item)
        self._drain()

    def _interrupt(self) -> None:
        """Telnet's Ctrl-C (IAC IP): break the job this connection started, and nothing else.

        The break's reply is not waited for here, so the timing mark that follows the interrupt
        is answered at once and telnet shows the lines that come after it."""
        job = self.app.jobs.current
        if job is None or job.connection != self.id or job.cancelled:
            self.log.info("telnet_interrupt", job="none")
            return
        self.log.info("telnet_interrupt", job=job.id)
        result = self.app.dispatch(self, b"break")
        if result is not None:
            asyncio.ensure_future(result)

    def eof_received(self) -> bool | None:
        # Let queued requests finish (a one-shot `printf 'status\n' | nc` still gets its answer);
        # the transport closes once the last reply is written.
        self._close_after_drain = True
        self.close_if_done()
        return True

    def close_if_done(self) -> None:
        """After the client's EOF: close once every request it sent has its final line."""
        if self._close_after_drain and not self.pending and self.waiting is None and not self.jobs_running:
            self.close()

    def connection_lost(self, exc: Exception | None) -> None:
        self.closed = True
        self.app.connections.discard(self)
        job = self.app.jobs.current
        if job is not None and job.connection == self.id:
            job.requester_gone.set()
        self.log.info("client_disconnected", clients=len(self.app.connections))

    # ------------------------------------------------------------ lines in

    _close_after_drain = False

    _drain_scheduled = False

    def _drain(self) -> None:
        budget = LINES_PER_TURN
        while self.pending and self.waiting is None and not self.closed:
            if budget == 0:  # let the other connections in; a flood costs only its sender
                if not self._drain_scheduled:
                    self._drain_scheduled = True
                    self.app.loop.call_soon(self._drain_later)
                break
            budget -= 1
            item = self.pending.popleft()
            if item is TIMING_MARK:  # RFC 860: answered once the input before it was handled
                if self.transport is not None:
                    self.transport.write(WILL_TIMING_MARK)
                continue
            assert not isinstance(item, Telnet)
            result = self.app.dispatch(self, item)
            if self.exiting:
                self.pending.clear()
                self.close()
                return
            if result is not None:
                self.waiting = asyncio.ensure_future(result)
                self.waiting.add_done_callback(self._resume)
        if self.transport is not None and not self.closed:
            if len(self.pending) > MAX_PENDING_LINES and not self.paused:
                self.transport.pause_reading()
                self.paused = True
            elif self.paused and len(self.pending) < MAX_PENDING_LINES // 2:
                self.transport.resume_reading()
                self.paused = False
        self.close_if_done()

    def _drain_later(self) -> None:
        self._drain_scheduled = False
        self._drain()

    def _resume(self, fut: asyncio.Future[Any]) -> None:
        self.waiting = None
        self._drain()

    # ------------------------------------------------------------ lines out

    def send(self, reply: Reply, *, job: bool = False) -> None:
        """``job``: a line of a job this connection started (App.job_reply), not an immediate reply."""
        self.app.sent(self, reply, job=job)  # also once the client is gone: a recording keeps every line
        if self.closed or self.transport is None or self.transport.is_closing():
            return
        line = format_reply_json(reply) + "\n" if self.json else format_reply(reply) + "\r\n"
        self.transport.write(line.encode("utf-8"))
        if self.transport.get_write_buffer_size() > MAX_OUTPUT_BYTES:
            self.log.warning("client_dropped", reason="not reading its replies")
            self.transport.abort()
            self.closed = True
            self.pending.clear()  # its unread requests go with it
            self.app.connections.discard(self)
            self.app.loop.call_soon(give_back_memory)  # once the aborted transport's buffer is freed

    def close(self) -> None:
        if self.transport is not None and not self.closed:
            self.closed = True
            self.transport.close()
        self.app.connections.discard(self)


def warm_up_kernels() -> None:
    """Compile (first run after installing) or load from cache the numba kernels."""
    from drivers.sim import raycast
    from prox_workflows.algorithms import bounds_map, dem2hazard, dem_import, planner, vehicle

    try:
        bounds_map.warm_up()
        dem_import.warm_up()
        dem2hazard.warm_up()
        planner.warm_up()
        vehicle.warm_up()
        raycast.warm_up()
        log.info("kernels_ready")
    except Exception as exc:  # noqa: BLE001 - the plain-Python paths still work
        log.warning("kernels_not_compiled", error=str(exc))


def freeze_start_heap() -> None:
    """Take what the start made out of the cyclic collector's walks. A full collection walks
    every tracked object with the GIL held: the start leaves some 160,000 (modules, numba's
    dispatchers, devices, the scene), a walk of 60-110 ms on the development machine every few
    minutes of jobs, that held status and every other connection up meanwhile. Frozen, a full collection walks only what was made since. The start's objects live as long
    as the server; one of them in a reference cycle let go while it runs (a replaced scene) stays
    until it stops, when :func:`serve` unfreezes them (a process may start another server)."""
    gc.collect()
    gc.freeze()


WARM_UP_THREAD = "rvs-warm-up"


def start_warm_up(stopping: asyncio.Event | None = None) -> None:
    """Warm the kernels up in a daemon thread of its own, not in the loop's executor: a compile
    cannot be cancelled, and asyncio.run joins the executor's threads at exit, so a Ctrl-C in
    the first seconds would wait (10-20 s, silently) for a compile nobody needs any more. Then
    the start's heap is frozen, unless the server already stops (its unfreeze may be done)."""

    def work() -> None:
        warm_up_kernels()
        if stopping is None or not stopping.is_set():
            freeze_start_heap()

    threading.Thread(target=work, name=WARM_UP_THREAD, daemon=True).start()


def _on_signal(app: App, sig: signal.Signals) -> None:
    """SIGINT/SIGTERM: say so, then shut down as quit does; a second one ends the process at
    once (a device that does not answer its close may hold the first one up)."""
    if app.stopping.is_set():
        log.warning("stopping_now", signal=sig.name, message="second signal: exiting without cleaning up")
        logging.shutdown()
        os._exit(128 + sig.value)
    log.info("stopping", signal=sig.name, message="stopping the server (send it again to exit at once)")
    app.stopping.set()


def listen(host: str, port: int) -> socket.socket:
    """Bind and listen before the devices open, so the port in the first log line already
    accepts; early clients wait in the backlog until the devices are up."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    return socket.create_server((host, port), family=family, backlog=512)


async def serve(app: App, sock: socket.socket, *, ready: Any = None, handle_signals: bool = True,
                web_sock: socket.socket | None = None, console_off: str | None = None) -> int:
    """Open the devices, serve until quit or a signal; returns the exit status. ``console_off``
    says why there is no ``web_sock`` (status and the log repeat it)."""
    loop = asyncio.get_running_loop()
    bound = sock.getsockname()
    log.info("listening", host=bound[0], port=bound[1], server=app.name, data=str(app.data_dir))
    app.console_off = console_off if web_sock is None else None
    if web_sock is None and app.server_cfg.web_port:  # wanted, but not to be had: say so at once
        log.warning("web_console_off", reason=app.console_off)
    if handle_signals:
        for sig in (signal.SIGINT, signal.SIGTERM):
            try:
                loop.add_signal_handler(sig, _on_signal, app, sig)
            except (NotImplementedError, RuntimeError):
                pass
    await loop.run_in_executor(None, app.devices.open_all)
    if not app.devices.healthy():
        app.set_mode("fault")
    if web_sock is not None:  # before the TCP server, so that every greeting says console=on
        # imported here, once, before the server serves: a server without a console (web_port 0)
        # does without aiohttp, a third of its start
        from .web.console import WebConsole

        try:
            app.console = WebConsole(app)
            await app.console.start(web_sock)
        except OSError as exc:
            web_sock.close()
            app.console, app.console_off = None, f"the web console did not start: {exc}"
            log.warning("web_console_off", reason=app.console_off)
    app.telemetry = Station(app)  # before the TCP server: the first request is already published
    await app.telemetry.start(console_host(app.server_cfg.host, app.server_cfg.token, app.server_cfg.web_public))
    server = await loop.create_server(lambda: Connection(app), sock=sock, backlog=512)
    if app.server_cfg.warm_up and not app.stopping.is_set():
        start_warm_up(app.stopping)  # the first DEM or plan then skips the JIT
    if ready is not None:
        ready(bound[1])
    try:
        await app.stopping.wait()
    finally:
        log.info("shutting_down")
        began = time.monotonic()
        await app.interrupt()
        if app.console is not None:
            await app.console.close()
        server.close()
        for conn in list(app.connections):
            conn.close()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(server.wait_closed(), 1.0)
        if app.telemetry is not None:
            await app.telemetry.close()
        app.jobs.shutdown()
        await loop.run_in_executor(None, app.stop_monitors)
        await loop.run_in_executor(None, app.devices.close)
        gc.unfreeze()  # what freeze_start_heap kept from the collector goes back to it: this server is let go
        # the last line: every job, connection, recording and device is closed (the process then
        # ends without finalising the interpreter, rvs_server.main)
        log.info("stopped", seconds=round(time.monotonic() - began, 3))
        if handle_signals:
            for sig in (signal.SIGINT, signal.SIGTERM):
                try:
                    loop.remove_signal_handler(sig)
                except (NotImplementedError, RuntimeError):
                    pass
    return 0
