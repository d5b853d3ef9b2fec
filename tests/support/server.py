"""The real server on a real TCP port, in a background thread, and a plain line client to it."""

from __future__ import annotations

import socket
import time
from pathlib import Path
from typing import Any

from rvs_server.client import session
from rvs_server.protocol import Reply, parse_reply

FINAL = ("OK", "ERROR")
# a ServerProcess's arguments for a world that takes no wall time, with no console or Foxglove, and
# no warm-up: loading the numba kernels in the background costs each server some 4 s of CPU (which
# every test server on the 2 cores pays), and its ~30 MB arrive while a test measures the resident
# memory; a job loads the kernels it needs when it first runs (ServerThread's servers do the same)
FAST = ("--set", "drivers.ptu.time_scale=0", "--set", "sim.time_scale=0",
        "--set", "server.web_port=0", "--set", "server.foxglove_port=0", "--set", "server.warm_up=false")


class LineClient:
    """A plain socket client: what a GNC program would do, with no help from the server's code."""

    def __init__(self, port: int, host: str = "127.0.0.1", timeout: float = 60.0) -> None:
        # The timeout is a safety net against a hang, not a speed bound: a loaded machine may
        # take seconds between two lines of a job.
        self.sock = socket.create_connection((host, port), timeout=timeout)
        self.buf = b""
        self.timeout = timeout
        self.greeting = self.line()

    def send(self, text: str | bytes) -> None:
        data = text if isinstance(text, bytes) else text.encode()
        if not data.endswith(b"\n"):
            data += b"\n"
        self.sock.sendall(data)

    def line(self, timeout: float | None = None) -> str:
        return self.raw_line(timeout)[:-1].decode().rstrip("\r")

    def raw_line(self, timeout: float | None = None) -> bytes:
        """The next line as sent, bytes and all, its LF included."""
        self.sock.settimeout(timeout or self.timeout)
        while b"\n" not in self.buf:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("server closed the connection")
            self.buf += chunk
        raw, self.buf = self.buf.split(b"\n", 1)
        return raw + b"\n"

    def reply(self, timeout: float | None = None) -> Reply:
        return parse_reply(self.line(timeout))

    def until_final(self, timeout: float | None = None, job: str | None = None) -> list[Reply]:
        """Replies up to the final line (of ``job`` if given; an ACK makes the job the target)."""
        out: list[Reply] = []
        while True:
            r = self.reply(timeout)
            out.append(r)
            if r.status == "ACK" and job is None:
                job = r.fields["job"]
                continue
            if r.status in FINAL and (job is None or r.fields.get("job") == job):
                return out

    def start_job(self, text: str, timeout: float | None = None) -> str:
        """Send a job request and return its job id (EVENT lines before the ACK are skipped)."""
        self.send(text)
        while True:
            r = self.reply(timeout)
            if r.status == "ACK":
                return r.fields["job"]
            if r.status in FINAL:
                raise AssertionError(f"job refused: {r}")

    def request(self, text: str, timeout: float | None = None) -> Reply:
        """Send one request and return its final line (skipping EVENT and PROGRESS lines)."""
        self.send(text)
        return self.until_final(timeout)[-1]

    def lines_before_status(self) -> list[Reply]:
        """Every line received before the answer to a status sent now: the server writes a
        connection's lines in order, so this collects the events caused by what came before."""
        self.send("status")
        out: list[Reply] = []
        while True:
            r = self.reply()
            if r.module == "EGP-RVS-STATUS":
                return out
            out.append(r)

    def __enter__(self) -> LineClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.sock.close()


class ServerThread(session.ServerThread):
    """The real server in a thread, with the tests' settings and a ``data`` folder."""

    def __init__(self, data: Path, overrides: list[str] | None = None, config_dir: str | None = None) -> None:
        # warm_up off: a hundred short-lived test servers would each load the numba kernels
        # sim.time_scale=0: the rover drives, and frames take, their simulated time in no wall time
        sets = [f"server.data={data}", "server.port=0", "drivers.ptu.time_scale=0", "sim.time_scale=0",
                "server.warm_up=false", "server.web_port=0", "server.foxglove_port=0", *(overrides or [])]
        super().__init__(sets, config_dir)
        self.data = data

    def client(self, **kw: Any) -> LineClient:
        return LineClient(self.port, **kw)

    def stop(self, timeout: float = 20.0) -> None:
        super().stop(timeout)


def wait_for(predicate: Any, timeout: float = 60.0, interval: float = 0.01) -> bool:
    """Poll until ``predicate()`` is true; the timeout is a safety net, not a speed bound."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return predicate()


def waiting_event(c: LineClient, timeout: float = 120) -> Reply:
    """The next ``EVENT kind=waiting`` (navigate waits for the GNC to drive a leg) on ``c``; an
    AssertionError when navigate ends first."""
    while True:
        r = c.reply(timeout)
        if r.status == "EVENT" and r.fields.get("kind") == "waiting":
            return r
        if r.status in ("OK", "ERROR") and r.module == "EGP-RVS-NAVIGATE":
            raise AssertionError(f"navigate ended before waiting: {r}")
