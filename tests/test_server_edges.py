"""Edges of the server through real sockets and real processes: the monitors' timing figures,
the web console's port, shutdown on a signal, and protocol corner cases (overlong lines,
comments, control characters, ranges the device gives)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import LineClient

from rvs_server.protocol import parse_reply

ROOT = Path(__file__).resolve().parent.parent


def test_monitor_mean_and_longest_cycle_cover_the_same_cycles(server_factory: Any, sim_time: Any,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """In simulated time every cycle lasts one frame, except the first, made to last ten (as
    one that fills the caches does): the mean may not count it where the maximum does not."""
    srv = server_factory(["server.scene=office"])
    c = srv.client()
    frame = 0.1
    sim = sim_time(srv.app, frame)
    tof = srv.app.devices.get("tof")
    gated = tof.grab_xyz
    frames = []

    def first_frame_slow(*args: Any, **kwargs: Any) -> Any:
        out = gated(*args, **kwargs)
        if not frames:
            sim.clock.start += 9 * frame  # the clock is counted in frames: this one took ten
        frames.append(1)
        return out

    monkeypatch.setattr(tof, "grab_xyz", first_frame_slow)
    assert c.request(f"hazard-start -period {frame}").status == "OK"
    sim.run(5)
    _, st = sim.sync(c, "hazard")
    assert int(st["hazard_cycles"]) == 5
    assert float(st["cycle_ms"]) <= float(st["cycle_ms_max"]), st
    assert float(st["cycle_ms"]) == pytest.approx(1000 * frame) == float(st["cycle_ms_max"]), st
    assert st["timed_cycles"] == "4", st  # the first is not timed
    r = c.request("hazard-stop")
    assert float(r.fields["cycle_ms"]) <= float(r.fields["cycle_ms_max"]) and r.fields["timed_cycles"] == "4", r


# ---------------------------------------------------------------------- the web console's port


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server_process(data: Path, *args: str) -> tuple[subprocess.Popen[str], int]:
    """``python -m rvs_server`` on a free port, as an operator starts it; (process, TCP port)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "rvs_server", "--port", "0", "--data", str(data),
         "--set", "drivers.ptu.time_scale=0", *args],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )
    first = proc.stderr.readline() if proc.stderr is not None else ""
    if "listening" not in first:
        proc.kill()
        rest = proc.communicate(timeout=30)[1]
        raise AssertionError(f"the server did not start: {first}{rest}")
    return proc, int(first.split("port=")[1].split()[0])


def stop_process(proc: subprocess.Popen[str], sig: int = signal.SIGTERM, timeout: float = 30.0) -> int:
    """Signal the server; its exit status (the timeout is a safety net against a hang)."""
    try:
        proc.send_signal(sig)
        return proc.wait(timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_taken_console_port_costs_the_console_not_the_server(tmp_path: Path) -> None:
    """A second server on a machine where one runs: --port given, the console's 7071 taken."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        web_port = taken.getsockname()[1]
        proc, port = start_server_process(tmp_path / "d", "--set", f"server.web_port={web_port}",
                                          "--set", "server.warm_up=false")
        try:
            with LineClient(port) as c:
                hello = parse_reply(c.greeting)
                assert list(hello.fields)[:4] == ["kind", "protocol", "server", "mode"]  # the contract's first
                assert hello.fields["console"] == "off", c.greeting
                st = c.request("status").fields
                assert st["console"] == "off" and str(web_port) in st["console_reason"], st
                assert "--web-port" in st["console_reason"], st
        finally:
            assert stop_process(proc) == 0
    log = [json.loads(line) for line in (tmp_path / "d" / "rvs.log").read_text().splitlines()]
    off = [e for e in log if e["event"] == "web_console_off"]
    assert off and off[0]["level"] == "warning" and str(web_port) in off[0]["reason"], off


def test_rvs_server_help_names_the_console_and_its_port() -> None:
    out = subprocess.run([sys.executable, "-m", "rvs_server", "--help"], capture_output=True, text=True,
                         timeout=120, cwd=ROOT)
    assert out.returncode == 0
    assert "--web-port" in out.stdout and "console" in out.stdout and "7071" in out.stdout, out.stdout


def test_hello_and_status_say_whether_the_console_runs(server_factory: Any) -> None:
    off = server_factory()  # the tests' servers run with server.web_port=0
    with off.client() as c:
        assert parse_reply(c.greeting).fields["console"] == "off"
        st = c.request("status").fields
        assert st["console"] == "off" and "web_port is 0" in st["console_reason"], st
    web_port = free_port()
    on = server_factory([f"server.web_port={web_port}"])
    with on.client() as c:
        assert parse_reply(c.greeting).fields["console"] == "on"
        st = c.request("status").fields
        assert st["console"] == "on" and st["console_url"] == f"http://127.0.0.1:{web_port}/", st


# ---------------------------------------------------------------------- stopping on a signal


def test_ctrl_c_stops_the_server_at_once_while_the_kernels_compile(tmp_path: Path) -> None:
    """An empty numba cache: the warm-up compiles for many seconds (10-20 s on the development
    machine), a compile that cannot be cancelled. Ctrl-C right after the greeting must not wait
    for it. The bound is generous for a loaded machine, and far below a compile."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))  # nothing cached: it compiles
    proc = subprocess.Popen(
        [sys.executable, "-m", "rvs_server", "--port", "0", "--data", str(tmp_path / "d"), "--web-port", "0"],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env,
    )
    try:
        assert proc.stderr is not None
        first = proc.stderr.readline()
        assert "listening" in first, first
        with LineClient(int(first.split("port=")[1].split()[0])) as c:
            assert parse_reply(c.greeting).fields["console"] == "off"
            st = c.request("status").fields  # --web-port 0 is server.web_port=0
            assert st["console"] == "off" and "web_port is 0" in st["console_reason"], st
            t0 = time.monotonic()
            proc.send_signal(signal.SIGINT)
            status = proc.wait(60)  # a safety net; the bound is below
            took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = proc.stderr.read()
    assert status == 0, err
    assert took < 5.0, f"SIGINT took {took:.1f} s"
    assert "stopping" in err and "SIGINT" in err, err  # the operator is told
