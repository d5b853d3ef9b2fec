"""One synchronous RVS connection with request/reply correlation, shared by rvs-client,
rvs-replay and their tests.

Replies to a request are told apart from everything else on the connection (EVENTs, late lines
of earlier jobs) by tag: each request goes out with an automatic ``@c<n>`` tag unless it has
its own, and the server puts ``tag=`` first on every line about it (PROTOCOL.md). A background
reader thread routes each incoming line either to the request being waited for or to an
"async" callback, so an interactive prompt can print EVENTs while the user types.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

from rvs_server.protocol import MAX_LINE, TAG_RE, ProtocolError, Reply, parse_reply

FINAL = ("OK", "ERROR")
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 7070
GREETING_WAIT = 5.0  # s: the JSON greeting follows format json's OK at once; an old server sends none


class SessionError(Exception):
    """The connection could not be made or was refused by the server."""


def port_number(text: str) -> int:
    """An argparse ``type`` for --port: the resolver would quietly wrap 99999 to another port."""
    import argparse

    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a port number") from None
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{port} is out of range 1-65535")
    return port


@dataclass
class Line:
    """One line received while a request was waited for.

    ``mine`` says whether it is about that request; ``shown`` is the line with the automatic
    tag removed, which is what people and replay scripts want to read.
    """

    text: str
    mine: bool = True
    shown: str = ""
    reply: Reply | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if not self.shown:
            self.shown = self.text
        if self.reply is None:
            self.reply = try_parse(self.text)

    @property
    def status(self) -> str | None:
        return self.reply.status if self.reply is not None else None


@dataclass
class Result:
    """What came back for one request; ``outcome`` is ok, error, timeout or closed."""

    request: str
    sent: str
    tag: str | None
    auto_tag: bool
    lines: list[Line] = field(default_factory=list)
    final: Line | None = None
    outcome: str = "pending"
    job: str | None = None

    @property
    def ok(self) -> bool:
        return self.outcome == "ok"

    @property
    def own(self) -> list[Line]:
        return [line for line in self.lines if line.mine]


def try_parse(text: str) -> Reply | None:
    try:
        return parse_reply(text)
    except ProtocolError:
        return None


def is_request(line: str) -> bool:
    """Blank and comment lines get no reply from the server, so they must not be waited for."""
    stripped = line.strip(" \t\r\n")
    return bool(stripped) and not stripped.startswith("#")


def prepare(line: str, auto: str) -> tuple[str, str | None, bool]:
    """The line to send, the tag its replies will carry (None: untagged), and whether it is ours.

    A line with its own tag keeps it; when that tag is invalid, or the tagged line would exceed
    the server's line limit, the server's ERROR comes back untagged, so it is waited for as such.
    """
    text = line.strip(" \t\r\n")
    if text.startswith("@"):
        first = text.split(None, 1)[0][1:]
        return text, (first if TAG_RE.fullmatch(first) else None), False
    sent = f"@{auto} {text}"
    if len(sent.encode("utf-8")) > MAX_LINE:
        return text, None, False
    return sent, auto, True


def strip_tag(line: str, tag: str) -> str:
    """``line`` without its ``tag=<tag>`` (text) or ``"tag":"<tag>"`` (JSON) key."""
    if line.startswith("{"):
        return line.replace(f',"tag":"{tag}"', "", 1)
    return re.sub(r"^(\S+ \S+) tag=" + re.escape(tag) + r"(?= |$)", r"\1", line, count=1)


class _Pending:
    def __init__(self, result: Result, on_line: Callable[[Line], None] | None) -> None:
        self.result = result
        self.on_line = on_line
        self.done = threading.Event()

    def claim(self, text: str, reply: Reply | None) -> Line | None:
        """The line as this request's if it is about it, else None; records finality."""
        res = self.result
        if reply is None or reply.tag != res.tag:
            return None
        if res.tag is None and reply.status not in FINAL:
            return None  # untagged requests only ever get one immediate ERROR line
        shown = strip_tag(text, res.tag) if res.auto_tag and res.tag else text
        line = Line(text, True, shown, reply)
        if reply.status == "ACK" and res.job is None:
            res.job = str(reply.fields.get("job"))
        elif reply.status in FINAL and (res.job is None or str(reply.fields.get("job")) == res.job):
            res.final = line
            res.outcome = "ok" if reply.status == "OK" else "error"
        return line


class Session:
    """A connection to an RVS server.

    ``on_async`` receives every line that is not about the request being waited for (EVENTs,
    late job lines); it runs in the reader thread. ``on_close`` runs there when the server
    closes the connection.
    """

    def __init__(
        self,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        *,
        on_async: Callable[[Line], None] | None = None,
        on_close: Callable[[], None] | None = None,
        tag_prefix: str = "c",
    ) -> None:
        self.host = host
        self.port = port
        self.on_async = on_async
        self.on_close = on_close
        self.tag_prefix = tag_prefix
        self.greeting: str | None = None
        self._greeted = threading.Event()
        self._sock: socket.socket | None = None
        self._buf = b""
        self._lock = threading.Lock()
        self._send_lock = threading.Lock()
        self._pending: _Pending | None = None
        self._reader: threading.Thread | None = None
        self._closed = threading.Event()
        self._n = 0
        # Automatic tags of requests given up on (Ctrl-C, timeout) before their final line: their
        # late lines still carry the tag, which the user never typed, so it is taken off them too.
        self._abandoned: set[str] = set()

    # ------------------------------------------------------------------ connection

    def connect(self, timeout: float = 10.0, retry_for: float = 0.0) -> str:
        """Connect and read the greeting (returned); retries refused connects for ``retry_for`` s,
        which is what a server that is still opening its devices needs."""
        deadline = time.monotonic() + retry_for
        while True:
            try:
                sock = socket.create_connection((self.host, self.port), timeout=timeout)
                break
            except ConnectionRefusedError:
                if time.monotonic() >= deadline:
                    raise
                time.sleep(0.05)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock
        try:
            greeting = self._read_line()
        except (OSError, TimeoutError) as exc:
            sock.close()
            raise SessionError(f"no greeting from {self.host}:{self.port}: {exc}") from None
        if greeting is None:
            sock.close()
            raise SessionError(f"{self.host}:{self.port} closed the connection before its greeting")
        self.greeting = greeting
        reply = try_parse(greeting)
        if reply is None or reply.status != "EVENT" or reply.fields.get("kind") != "hello":
            sock.close()
            raise SessionError(f"{self.host}:{self.port} refused the connection: {greeting}")
        sock.settimeout(None)
        self._reader = threading.Thread(target=self._read_loop, name="rvs-session-reader", daemon=True)
        self._reader.start()
        return greeting

    @property
    def closed(self) -> bool:
        return self._closed.is_set()

    def close(self) -> None:
        sock = self._sock
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()
        if self._reader is not None and self._reader is not threading.current_thread():
            self._reader.join(timeout=2.0)
        self._closed.set()

    def __enter__(self) -> Session:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    # ------------------------------------------------------------------ requests

    def set_format(self, fmt: str, timeout: float | None = None) -> Result:
        """``format text|json``. Said at connect time, ``format json`` makes the server send its
        greeting again in JSON; that one becomes :attr:`greeting`, so a JSON client never has to
        parse the text greeting."""
        self._greeted.clear()
        result = self.request(f"format {fmt}", timeout=timeout)
        if result.ok and fmt == "json":
            self._greeted.wait(GREETING_WAIT if timeout is None else min(timeout, GREETING_WAIT))
        return result

    def next_tag(self) -> str:
        self._n += 1
        return f"{self.tag_prefix}{self._n}"

    def request(
        self, line: str, *, timeout: float | None = None, on_line: Callable[[Line], None] | None = None
    ) -> Result:
        """Send one request and wait for its final line (an ACK'ed job's OK/ERROR).

        ``on_line`` sees each of the request's own lines as it arrives (in the reader thread).
        Other lines arriving meanwhile go to ``on_async`` and are also kept in the result, in
        arrival order, so a replay can match an expected EVENT. A KeyboardInterrupt while
        waiting stops the wait; later lines of the request then go to ``on_async``, shown
        without the automatic tag as its own lines were.
        """
        if "\n" in line or "\r" in line:
            raise ValueError("one request per line: the text must not contain a line break")
        if not is_request(line):
            raise ValueError("blank and comment lines get no reply; do not send them as requests")
        sent, tag, auto = prepare(line, self.next_tag())
        result = Result(line.strip(" \t"), sent, tag, auto)
        if self._sock is None or self.closed:
            result.outcome = "closed"
            return result
        pending = _Pending(result, on_line)
        with self._lock:
            self._pending = pending
        try:
            try:
                with self._send_lock:
                    self._sock.sendall((sent + "\n").encode("utf-8"))
            except OSError:
                result.outcome = "closed"
                return result
            if not pending.done.wait(timeout):
                result.outcome = "timeout"
            elif result.final is None:
                result.outcome = "closed"
        finally:
            with self._lock:
                if self._pending is pending:
                    self._pending = None
                if result.final is None and result.auto_tag and result.tag is not None:
                    self._abandoned.add(result.tag)  # under the lock: no late line slips between
        return result

    def _late_shown(self, text: str, reply: Reply | None) -> str:
        """A line about no pending request as people should read it: a late line of a request
        given up on loses the automatic tag (and the tag is forgotten at its final line).
        Called with the lock held."""
        tag = reply.tag if reply is not None else None
        if tag is None or tag not in self._abandoned:
            return text
        if reply is not None and reply.status in FINAL:
            self._abandoned.discard(tag)
        return strip_tag(text, tag)

    # ------------------------------------------------------------------ reading

    def _read_line(self) -> str | None:
        """One line from the socket (None at end of stream); only the reader thread uses it
        once the greeting is read."""
        assert self._sock is not None
        while b"\n" not in self._buf:
            chunk = self._sock.recv(65536)
            if not chunk:
                rest, self._buf = self._buf, b""
                return rest.decode("utf-8", "replace").rstrip("\r") if rest else None
            self._buf += chunk
        raw, self._buf = self._buf.split(b"\n", 1)
        return raw.decode("utf-8", "replace").rstrip("\r")

    def _read_loop(self) -> None:
        try:
            while True:
                try:
                    text = self._read_line()
                except OSError:
                    text = None
                if text is None:
                    break
                self._route(text)
        finally:
            self._closed.set()
            with self._lock:
                pending = self._pending
            if pending is not None:
                pending.done.set()
            if self.on_close is not None:
                with contextlib.suppress(Exception):
                    self.on_close()

    def _route(self, text: str) -> None:
        reply = try_parse(text)
        if reply is not None and reply.status == "EVENT" and reply.fields.get("kind") == "hello":
            self.greeting = text  # the greeting again, in JSON (set_format): not news for on_async
            self._greeted.set()
            return
        with self._lock:
            pending = self._pending
            line = pending.claim(text, reply) if pending is not None else None
            if line is None:
                line = Line(text, False, self._late_shown(text, reply), reply)
            if pending is not None:
                pending.result.lines.append(line)
        callback = (pending.on_line if pending is not None else None) if line.mine else self.on_async
        if callback is not None:
            try:
                callback(line)
            except Exception as exc:  # noqa: BLE001 - a printing error must not kill the reader
                print(f"rvs session: line callback failed: {exc!r}", file=sys.stderr)
        if line.mine and pending is not None and pending.result.final is line:
            pending.done.set()


# ---------------------------------------------------------------------- a server of one's own


class ServerThread:
    """The real server (the same code path as rvs-server) on an ephemeral port in a thread of
    this process, for tests and benchmarks that want its ``app`` at hand: ``sets`` are the
    ``--set`` overrides (``server.data=...`` among them); the log goes to the server's own log
    file in its data folder. Like :class:`ServerProcess` it takes no web console or Foxglove
    port unless ``sets`` give one: those ports may be an operator's real server's, and publishing
    to Foxglove would weigh on what a benchmark measures."""

    def __init__(self, sets: Sequence[str], config_dir: str | None = None, log_level: str = "info") -> None:
        from rvs_server.main import build_config

        self.store = build_config(config_dir, ["server.web_port=0", "server.foxglove_port=0", *sets])
        server = self.store.get("server")
        self.port = 0
        self.app: Any = None
        self.loop: asyncio.AbstractEventLoop | None = None
        self.exit_code: int | None = None
        self._log = (Path(server.data) / server.log_file, log_level)
        self._ready = threading.Event()
        self.thread = threading.Thread(target=self._main, daemon=True)

    def _main(self) -> None:
        from rvs_server.main import run

        async def go() -> int:
            self.loop = asyncio.get_running_loop()

            def ready(port: int) -> None:
                self.port = port
                self._ready.set()

            def on_app(app: Any) -> None:
                self.app = app

            return await run(self.store, ready=ready, handle_signals=False, on_app=on_app)

        try:
            self.exit_code = asyncio.run(go())
        finally:
            self._ready.set()

    def start(self, timeout: float = 60.0) -> ServerThread:
        from rvs_server.logs import setup as setup_logging

        setup_logging(self._log[1], self._log[0], console=False)
        self.thread.start()
        if not self._ready.wait(timeout) or not self.port:
            raise RuntimeError("server did not start")
        return self

    def stop(self, timeout: float = 30.0) -> None:
        if self.loop is not None and self.thread.is_alive():
            self.loop.call_soon_threadsafe(self.app.stopping.set)
        self.thread.join(timeout)


class ServerProcess:
    """A fresh simulated ``rvs_server`` in a child process on a free port, for replays and tests.

    The port comes from the server's first log line (``listening ... port=NNNNN``); stderr goes
    to a file in the data directory so a chatty server can never block on a full pipe.
    """

    LISTENING = re.compile(r"listening.*?\bport=(\d+)")

    def __init__(self, data_dir: str | os.PathLike[str] | None = None, extra_args: Sequence[str] = ()) -> None:
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        if data_dir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="rvs-server-")
            data_dir = self._tmp.name
        self.data_dir = Path(data_dir)
        self.extra_args = list(extra_args)
        self.port = 0
        self.proc: subprocess.Popen[bytes] | None = None
        self.log_path = self.data_dir / "server.stderr"

    def start(self, timeout: float = 30.0) -> int:
        self.data_dir.mkdir(parents=True, exist_ok=True)
        root = str(Path(__file__).resolve().parents[1])  # so a source checkout works uninstalled
        env = dict(os.environ)
        env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
        # a throwaway server takes no web console or Foxglove port (7071 and 8765 may be the operator's real server's)
        cmd = [sys.executable, "-m", "rvs_server", "--port", "0", "--data", str(self.data_dir),
               "--set", "server.web_port=0", "--set", "server.foxglove_port=0", *self.extra_args]
        with open(self.log_path, "wb") as err:
            self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err, env=env)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            text = self.log_path.read_text("utf-8", "replace")
            m = self.LISTENING.search(re.sub(r"\x1b\[[0-9;]*m", "", text))
            if m:
                self.port = int(m.group(1))
                return self.port
            if self.proc.poll() is not None:
                break
            time.sleep(0.02)
        tail = self.log_tail()  # read before stop() removes a temporary data directory
        self.stop()
        raise SessionError(f"the server exited or did not start within {timeout:g} s; its log ends:\n{tail}")

    def log_tail(self, n: int = 20) -> str:
        try:
            return "\n".join(self.log_path.read_text("utf-8", "replace").splitlines()[-n:])
        except OSError:
            return ""

    def stop(self, timeout: float = 10.0) -> int | None:
        """SIGTERM, as an operator would; the exit status (None if it had to be killed)."""
        proc, self.proc = self.proc, None
        status: int | None = None
        if proc is not None:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            try:
                status = proc.wait(timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        return status

    def __enter__(self) -> ServerProcess:
        self.start()
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.stop()


