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
from pathlib import Path
from typing import Any

import pytest
from support.server import LineClient

from rvs_server.protocol import parse_reply

ROOT = Path(__file__).resolve().parents[2]


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
    for it: the process ends before the warm-up logs that the kernels are ready."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))  # nothing cached: it compiles
    proc = subprocess.Popen(
        [sys.executable, "-m", "rvs_server", "--port", "0", "--data", str(tmp_path / "d"), "--web-port", "0",
         "--foxglove-port", "0"],
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
            assert st["foxglove"] == "off", st  # --foxglove-port 0 is server.foxglove_port=0
            proc.send_signal(signal.SIGINT)
            status = proc.wait(60)  # a safety net: a compile takes 10-20 s
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = proc.stderr.read()
    assert status == 0, err
    log = "".join(p.read_text() for p in (tmp_path / "d").rglob("*.log"))
    assert "SIGINT" in log and "kernels_ready" not in log, log  # stopped while the kernels compiled
    assert "stopping" in err and "SIGINT" in err, err  # the operator is told


def test_ctrl_c_with_foxglove_and_a_recording_shuts_down_cleanly_and_ends_the_process(tmp_path: Path) -> None:
    """The server as an operator runs it (Foxglove on, a recording going): Ctrl-C finishes the
    recording, closes everything, says so in its last log line and ends the process, status 0.
    (What it costs is measured in the commit: 1.7-2.7 s at load 14 before, 0.16-0.36 s after.)"""
    proc = subprocess.Popen(
        [sys.executable, "-m", "rvs_server", "--port", "0", "--data", str(tmp_path / "d"), "--web-port", "0",
         "--foxglove-port", str(free_port())],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT,
    )
    try:
        assert proc.stderr is not None
        first = proc.stderr.readline()
        assert "listening" in first, first
        with LineClient(int(first.split("port=")[1].split()[0])) as c:
            assert c.request("status").fields["foxglove"] == "on"
            r = c.request("record -start -name run", timeout=60)
            assert r.status == "OK", r.fields
            assert c.request("sim truth").status == "OK"
            proc.send_signal(signal.SIGINT)
            status = proc.wait(60)  # a safety net, not a speed bound
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    err = proc.stderr.read()
    assert status == 0, err
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert any("recording_stopped" in line and "run" in line for line in lines), err
    assert "stopped " in lines[-1] and "[rvs.server]" in lines[-1] and "seconds=" in lines[-1], lines[-3:]
    recordings = list((tmp_path / "d").rglob("run*.mcap"))
    assert len(recordings) == 1 and recordings[0].stat().st_size > 1000, recordings


# ---------------------------------------------------------------------- protocol corners


def test_a_too_long_line_keeps_its_tag(client: LineClient) -> None:
    client.send(b"@t77 grab-tof -output " + b"x" * 5000 + b"\n")
    r = client.reply()
    assert (r.module, r.tag, r.fields["code"]) == ("RVS", "t77", "E_TOOLONG"), r
    # cut before its LF arrives (the server discards as it reads): the tag is still known
    client.sock.sendall(b"@g.8:x-y version -" + b"y" * 4200)
    client.sock.sendall(b"zzz\n@t9 version\n")
    r = client.reply()
    assert (r.tag, r.fields["code"]) == ("g.8:x-y", "E_TOOLONG"), r
    assert client.reply().tag == "t9"
    client.send(b"version " + b"z" * 5000)  # no tag, none made up
    r = client.reply()
    assert (r.tag, r.fields["code"]) == (None, "E_TOOLONG"), r


def test_comment_and_blank_lines_get_no_reply_even_when_not_utf8(client: LineClient) -> None:
    client.send(b"# caf\xe9 (latin-1)\n   #\xc3\x28\xff\xfe\n \t \n@t1 version\n")
    r = client.reply()
    assert (r.module, r.tag) == ("EGP-RVS-VERSION", "t1"), r
    client.send(b"status \xc3\x28\n")  # a request that is not UTF-8 is still E_SYNTAX
    assert client.reply().fields["code"] == "E_SYNTAX"


def test_control_characters_from_the_client_are_shown_not_sent(client: LineClient) -> None:
    """Ctrl-L, BEL, NUL and an ESC sequence echoed raw would clear, ring and drive the
    operator's terminal: every reply shows them in caret notation, JSON escapes them."""
    client.send(b"\x0c\x07\x00\x1b[2J\n")
    line = client.raw_line()
    assert not any(b < 0x20 for b in line.rstrip(b"\r\n")), line
    r = parse_reply(line.decode())
    assert r.fields["code"] == "E_UNKNOWN" and "'^L^G^@^[[2J'" in r.fields["message"], r
    client.send(b"sleep -seconds 1\x07\x7f")  # a bad option value, quoted back
    r = parse_reply(client.raw_line().decode())
    assert r.fields["code"] == "E_ARG" and "1^G^?" in r.fields["message"], r
    client.send("format json")
    assert client.reply().fields["format"] == "json"
    assert client.reply().fields["kind"] == "hello"  # again, in JSON (no job started yet)
    client.send(b"\x0c\xc2\x9b\x7f\n")  # C0, C1 (CSI) and DEL
    line = client.raw_line()
    assert not any(b < 0x20 or b == 0x7f for b in line.rstrip(b"\n")) and b"\xc2\x9b" not in line, line
    assert "'\x0c\x9b\x7f'" in json.loads(line)["message"]  # JSON carries them exactly


def test_move_ptu_ranges_in_help_are_the_units_limits(server: Any, client: LineClient) -> None:
    limits = server.app.devices.devices["ptu"].status()["limits"]
    pan = f"[{limits['pan']['min_deg']:.2f}, {limits['pan']['max_deg']:.2f}]"
    tilt = f"[{limits['tilt']['min_deg']:.2f}, {limits['tilt']['max_deg']:.2f}]"
    assert (pan, tilt) == ("[-158.91, 158.91]", "[-46.65, 31.06]")  # the simulated D46's
    h = client.request("help move-ptu").fields
    assert pan in h["opt_pan"] and tilt in h["opt_tilt"], h
    for option in ("-pan 200", "-pan 400", "-tilt -60", "-tilt 100"):  # beyond, and far beyond
        r = client.request(f"move-ptu {option}")
        assert r.fields["code"] == "E_ARG", r
        assert (pan if "pan" in option else tilt) in r.fields["message"], r
    r = client.request("move-ptu -pan 158.9 -tilt -46.6")
    assert r.status == "OK", r


def test_config_shows_an_unset_float_as_none(client: LineClient) -> None:
    client.send("config -module move-ptu")
    line = client.line()
    assert "pan=none" in line.split() and "tilt=none" in line.split(), line
    client.send("format json")
    assert client.reply().fields["format"] == "json"
    assert client.reply().fields["kind"] == "hello"  # again, in JSON (no job started yet)
    client.send("config -module move-ptu")
    settings = json.loads(client.line())["settings"]
    assert settings == {"pan": None, "tilt": None}, settings
