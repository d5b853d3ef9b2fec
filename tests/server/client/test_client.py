"""rvs-client and the session it shares with rvs-replay, against real servers in child processes."""

from __future__ import annotations

import contextlib
import io
import json
import os
import pty
import select
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from rvs_server.client import console as client
from rvs_server.client.session import Line, ServerProcess, Session, SessionError, prepare, strip_tag
from rvs_server.protocol import parse_reply

ROOT = Path(__file__).resolve().parents[3]
FAST = ["--set", "drivers.ptu.time_scale=0", "--set", "sim.time_scale=0",  # a simulated world that takes no wall time
        "--set", "server.web_port=0", "--set", "server.foxglove_port=0"]  # no console or Foxglove (parallel servers would share their ports)


@pytest.fixture(scope="module")
def server() -> Iterator[ServerProcess]:
    with ServerProcess(extra_args=FAST) as srv:
        yield srv


@pytest.fixture
def session(server: ServerProcess) -> Iterator[Session]:
    with Session("127.0.0.1", server.port) as s:
        s.connect()
        yield s


def run_client(capsys: pytest.CaptureFixture[str], port: int, *args: str) -> tuple[int, list[str], str]:
    rc = client.main(["--port", str(port), *args])
    out, err = capsys.readouterr()
    return rc, out.splitlines(), err


def replies(lines: list[str]) -> list[tuple[str, str]]:
    return [(r.module, r.status) for r in map(parse_reply, lines)]


# ---------------------------------------------------------------------- correlation helpers


def test_prepare_adds_an_auto_tag_unless_the_request_has_one() -> None:
    assert prepare("  status ", "c1") == ("@c1 status", "c1", True)
    assert prepare("@mine status", "c2") == ("@mine status", "mine", False)
    # an invalid tag is answered untagged, so the request is waited for as untagged
    assert prepare("@bad! status", "c3") == ("@bad! status", None, False)
    # a tag that would push the line over the server's limit is left off
    long = "help " + "x" * 4090
    assert prepare(long, "c4") == (long, None, False)


def test_strip_tag_removes_only_the_auto_tag() -> None:
    assert strip_tag("EGP-RVS-SLEEP ACK tag=c1 job=3", "c1") == "EGP-RVS-SLEEP ACK job=3"
    assert strip_tag("EGP-RVS-STATUS OK tag=c1", "c1") == "EGP-RVS-STATUS OK"
    assert strip_tag("EGP-RVS-STATUS OK tag=c12 mode=ready", "c1") == "EGP-RVS-STATUS OK tag=c12 mode=ready"
    assert strip_tag('{"module":"X","status":"OK","tag":"c1","job":3}', "c1") == '{"module":"X","status":"OK","job":3}'


# ---------------------------------------------------------------------- session


def test_session_correlates_job_lines_and_keeps_events_apart(session: Session) -> None:
    seen: list[Line] = []
    result = session.request("sleep -seconds 0.05", timeout=30, on_line=seen.append)
    assert result.ok and result.auto_tag and result.tag is not None
    assert [line.status for line in result.own] == ["ACK", "OK"]
    assert result.own[0].reply.fields["job"] == result.final.reply.fields["job"] == result.job
    assert all(f"tag={result.tag}" not in line.shown for line in result.own)
    assert seen == result.own  # the callback sees the request's own lines, nothing else
    assert all(line.status == "EVENT" for line in result.lines if not line.mine)


def test_late_job_lines_after_a_timeout_go_to_the_async_callback(server: ServerProcess) -> None:
    late: list[Line] = []
    with Session("127.0.0.1", server.port, on_async=late.append) as s:
        s.connect()
        slow = s.request("sleep -seconds 60", timeout=0.2)
        assert slow.outcome == "timeout" and [line.status for line in slow.own] == ["ACK"]
        brk = s.request("break", timeout=30)
        assert brk.ok and brk.final.reply.fields["interrupted"] == slow.job
        back = s.request("continue", timeout=30)
        assert back.ok and back.final.reply.fields["mode"] == "ready"
    interrupted = [line.reply for line in late if line.reply is not None and line.reply.tag == slow.tag]
    assert [(r.status, r.fields["code"]) for r in interrupted] == [("ERROR", "E_INTERRUPTED")]


def test_untagged_error_of_a_bad_tag_is_still_the_final_line(session: Session) -> None:
    result = session.request("@bad! status", timeout=10)
    assert result.outcome == "error" and result.tag is None
    assert result.final.reply.fields["code"] == "E_SYNTAX"
    assert session.request("version", timeout=10).ok  # nothing left over to confuse the next one


def test_session_refuses_blank_requests(session: Session) -> None:
    with pytest.raises(ValueError):
        session.request("# just a comment")
    with pytest.raises(ValueError):
        session.request("status\nhelp")


# ---------------------------------------------------------------------- one-shot


def test_one_shot_prints_both_replies_and_no_greeting(server: ServerProcess, capsys: pytest.CaptureFixture[str]) -> None:
    rc, lines, _ = run_client(capsys, server.port, "-c", "status", "-c", "help")
    assert rc == 0
    assert replies(lines) == [("EGP-RVS-STATUS", "OK"), ("EGP-RVS-HELP", "OK")]
    assert parse_reply(lines[0]).tag is None  # the auto tag is not shown


def test_verbose_one_shot_prints_the_greeting(server: ServerProcess, capsys: pytest.CaptureFixture[str]) -> None:
    rc, lines, _ = run_client(capsys, server.port, "-v", "-c", "version")
    assert rc == 0
    hello = parse_reply(lines[0])
    assert (hello.status, hello.fields["kind"]) == ("EVENT", "hello")
    assert replies(lines[1:]) == [("EGP-RVS-VERSION", "OK")]


def test_an_error_makes_the_exit_status_non_zero(server: ServerProcess, capsys: pytest.CaptureFixture[str]) -> None:
    rc, lines, _ = run_client(capsys, server.port, "-c", "frobnicate", "-c", "version")
    assert rc == 1
    first = parse_reply(lines[0])
    assert (first.module, first.status, first.fields["code"]) == ("RVS", "ERROR", "E_UNKNOWN")
    assert replies(lines[1:]) == [("EGP-RVS-VERSION", "OK")]  # later requests still run


def test_a_job_request_waits_for_its_final_line(server: ServerProcess, capsys: pytest.CaptureFixture[str]) -> None:
    rc, lines, _ = run_client(capsys, server.port, "-c", "sleep -seconds 0.2", "-c", "status")
    assert rc == 0
    own = [parse_reply(line) for line in lines if parse_reply(line).status != "EVENT"]
    assert [(r.module, r.status) for r in own] == [
        ("EGP-RVS-SLEEP", "ACK"), ("EGP-RVS-SLEEP", "OK"), ("EGP-RVS-STATUS", "OK")
    ]
    assert own[0].fields["job"] == own[1].fields["job"]
    assert own[2].fields["job"] == "none"  # status went out only after the job had ended


def test_user_tags_are_kept(server: ServerProcess, capsys: pytest.CaptureFixture[str]) -> None:
    rc, lines, _ = run_client(capsys, server.port, "-c", "@mine sleep -seconds 0")
    assert rc == 0
    own = [parse_reply(line) for line in lines if parse_reply(line).status != "EVENT"]
    assert [(r.status, r.tag) for r in own] == [("ACK", "mine"), ("OK", "mine")]


def test_stdin_mode_skips_blank_and_comment_lines(
    server: ServerProcess, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(sys, "stdin", io.StringIO("status\n\n   \n# a note\nversion\nfrobnicate\n"))
    rc, lines, _ = run_client(capsys, server.port)
    assert rc == 1
    assert replies(lines) == [("EGP-RVS-STATUS", "OK"), ("EGP-RVS-VERSION", "OK"), ("RVS", "ERROR")]


def test_json_mode_prints_json_lines(server: ServerProcess, capsys: pytest.CaptureFixture[str]) -> None:
    rc, lines, _ = run_client(capsys, server.port, "--json", "-c", "status", "-c", "@t version")
    assert rc == 0
    objs = [json.loads(line) for line in lines]
    assert [(o["module"], o["status"]) for o in objs] == [("EGP-RVS-STATUS", "OK"), ("EGP-RVS-VERSION", "OK")]
    assert "tag" not in objs[0] and objs[1]["tag"] == "t"
    assert isinstance(objs[0]["clients"], int)


def test_no_server_is_exit_status_2(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    rc, _, err = run_client(capsys, port, "-c", "status")
    assert rc == 2 and "cannot talk to" in err


def test_token_is_sent_first(capsys: pytest.CaptureFixture[str]) -> None:
    with ServerProcess(extra_args=[*FAST, "--set", "server.token=s3cret"]) as srv:
        rc, lines, _ = run_client(capsys, srv.port, "-c", "status")
        assert rc == 1 and parse_reply(lines[0]).fields["code"] == "E_AUTH"
        rc, lines, _ = run_client(capsys, srv.port, "--token", "s3cret", "-c", "status")
        assert rc == 0 and replies(lines) == [("EGP-RVS-STATUS", "OK")]
        rc, lines, _ = run_client(capsys, srv.port, "--token", "wrong", "-c", "status")
        assert rc == 1 and replies(lines) == [("EGP-RVS-AUTH", "ERROR")]


def test_quit_ends_the_server_and_the_session_sees_it_close(capsys: pytest.CaptureFixture[str]) -> None:
    with ServerProcess(extra_args=FAST) as srv:
        closed: list[bool] = []
        with Session("127.0.0.1", srv.port, on_close=lambda: closed.append(True)) as watcher:
            watcher.connect()
            rc, lines, _ = run_client(capsys, srv.port, "-c", "quit")
            assert rc == 0 and replies(lines) == [("EGP-RVS-QUIT", "OK")]
            assert srv.proc is not None and srv.proc.wait(10) == 0
            deadline = time.monotonic() + 60  # a safety net: the close is seen at once
            while not watcher.closed and time.monotonic() < deadline:
                time.sleep(0.01)
            assert watcher.closed and closed == [True]
            assert watcher.request("status").outcome == "closed"


def test_request_after_close_reports_closed(server: ServerProcess) -> None:
    s = Session("127.0.0.1", server.port)
    s.connect()
    s.close()
    assert s.request("status").outcome == "closed"


def test_a_server_that_is_full_is_a_session_error() -> None:
    with ServerProcess(extra_args=[*FAST, "--set", "server.max_clients=1"]) as srv, Session("127.0.0.1", srv.port) as first:
        first.connect()
        with pytest.raises(SessionError, match="E_BUSY"):
            Session("127.0.0.1", srv.port).connect()


# ---------------------------------------------------------------------- interactive


def _read_until(fd: int, buf: bytearray, needle: bytes, limit: float = 15.0) -> bool:
    end = time.monotonic() + limit
    while needle not in buf and time.monotonic() < end:
        ready, _, _ = select.select([fd], [], [], 0.1)
        if ready:
            try:
                chunk = os.read(fd, 4096)
            except OSError:
                break
            if not chunk:
                break
            buf += chunk
    return needle in buf


def test_interactive_prints_greeting_replies_and_events_at_the_prompt(server: ServerProcess, tmp_path: Path) -> None:
    history = tmp_path / "history"
    master, slave = pty.openpty()
    env = dict(os.environ, RVS_CLIENT_HISTORY=str(history), TERM="dumb")
    proc = subprocess.Popen([sys.executable, "-m", "rvs_server.client.console", "--port", str(server.port)],
                            stdin=slave, stdout=slave, stderr=slave, env=env, cwd=ROOT)
    os.close(slave)
    buf = bytearray()
    try:
        assert _read_until(master, buf, b"rvs> ")
        assert b"RVS EVENT kind=hello" in buf
        os.write(master, b"version\n")
        assert _read_until(master, buf, b"EGP-RVS-VERSION OK")
        # another client changes the mode while this one sits at its prompt
        with Session("127.0.0.1", server.port) as other:
            other.connect()
            assert other.request("standby", timeout=10).ok
            assert other.request("continue", timeout=30).ok
        assert _read_until(master, buf, b"RVS EVENT kind=mode mode=standby")
        os.write(master, b"\x04")  # Ctrl-D leaves
        assert proc.wait(15) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)
    assert "version" in history.read_text().splitlines()


@contextlib.contextmanager
def _in_a_terminal(server: ServerProcess, tmp_path: Path) -> Iterator[tuple[subprocess.Popen[bytes], int]]:
    """rvs-client at the prompt of a real pseudo-terminal (``--progress lines``): the process and
    the terminal's master end, both ended on leaving."""
    master, slave = pty.openpty()
    env = dict(os.environ, RVS_CLIENT_HISTORY=str(tmp_path / "history"), TERM="dumb")
    # as a terminal starts it: with Ctrl-C's default action (a test worker may ignore SIGINT, and
    # a Python started with SIGINT ignored never raises KeyboardInterrupt)
    proc = subprocess.Popen([sys.executable, "-m", "rvs_server.client.console", "--port", str(server.port),
                             "--progress", "lines"], stdin=slave, stdout=slave, stderr=slave, env=env, cwd=ROOT,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    os.close(slave)
    try:
        yield proc, master
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)


def _ctrl_c_after_ack(proc: subprocess.Popen, master: int, buf: bytearray, line: bytes, module: bytes) -> None:
    """Type a job at the prompt and press Ctrl-C once its ACK is shown."""
    assert _read_until(master, buf, b"rvs> ")
    os.write(master, line + b"\n")
    assert _read_until(master, buf, module + b" ACK job="), buf.decode()
    proc.send_signal(signal.SIGINT)
    assert _read_until(master, buf, b"stopped waiting"), buf.decode()


def test_after_ctrl_c_the_late_lines_carry_no_tag_the_user_never_typed(server: ServerProcess, tmp_path: Path) -> None:
    """Ctrl-C stops the wait for a job, not the job: its OK prints when it comes, as its ACK
    did, without the automatic ``tag=c<n>`` the client added."""
    buf = bytearray()
    with _in_a_terminal(server, tmp_path) as (proc, master):
        _ctrl_c_after_ack(proc, master, buf, b"sleep -seconds 2", b"EGP-RVS-SLEEP")
        assert _read_until(master, buf, b"EGP-RVS-SLEEP OK job="), buf.decode()
        os.write(master, b"@mine version\n")  # a tag the user typed stays
        assert _read_until(master, buf, b"EGP-RVS-VERSION OK tag=mine"), buf.decode()
    text = buf.decode()
    assert "tag=c" not in text, text


@pytest.mark.parametrize("port", ["99999", "0", "http"])
def test_a_port_out_of_range_is_one_error_line_not_another_port(port: str, capsys: pytest.CaptureFixture[str]) -> None:
    """The resolver wraps 99999 to 34463: the client would talk to whatever listens there."""
    from rvs_server.client import replay

    for tool in (client.main, replay.main):
        with pytest.raises(SystemExit) as exc:
            tool(["--port", port, "-c", "status"] if tool is client.main else ["--port", port, "x.rvs"])
        err = capsys.readouterr().err
        assert exc.value.code == 2 and ": argument --port: " in err and "Traceback" not in err and err.count("\n") == 1


class _Typed:
    """readline as the Printer sees it: what the user has typed at the prompt so far."""

    @staticmethod
    def get_line_buffer() -> str:
        return "stat"


def test_after_ctrl_c_a_jobs_progress_does_not_redraw_the_prompt_under_every_line() -> None:
    """Ctrl-C stopped the wait for a job and the user is back at the prompt, typing: the job's
    PROGRESS lines go by without printing (each would redraw ``rvs> `` under it), its final line
    prints above the prompt once, with what was typed kept."""
    for bar in (False, True):
        out = io.StringIO()
        printer = client.Printer(out, _Typed(), bar=bar)
        printer.at_prompt = True
        for done in range(1, 6):
            printer.reply(Line(f"EGP-RVS-DEM-FULL-TOF PROGRESS job=3 phase=acquire done={done} total=24 "
                               f"message=\"view {done}/24\""))
        printer.reply(Line("EGP-RVS-DEM-FULL-TOF OK job=3 dem=dem/x_dem.tif"))
        text = out.getvalue()
        assert "PROGRESS" not in text and "view " not in text, text
        assert text.count(client.PROMPT) == 1, text
        assert text == f"\r\x1b[2KEGP-RVS-DEM-FULL-TOF OK job=3 dem=dem/x_dem.tif\n{client.PROMPT}stat", text


def test_after_ctrl_c_the_prompt_is_not_redrawn_under_each_progress_line(server: ServerProcess, tmp_path: Path) -> None:
    """rvs-client in a real terminal: Ctrl-C stops the wait for a job that goes on sending
    PROGRESS lines (a two-view dem-full-tof: a dozen of them); none of them prints at the prompt,
    each of which would redraw ``rvs> `` under it, and the job's final line prints once."""
    buf = bytearray()
    with _in_a_terminal(server, tmp_path) as (proc, master):
        _ctrl_c_after_ack(proc, master, buf, b"dem-full-tof -range -30,30,-40,-20 -name ctrlc", b"EGP-RVS-DEM-FULL-TOF")
        stopped = buf.index(b"stopped waiting")
        assert _read_until(master, buf, b"EGP-RVS-DEM-FULL-TOF OK job=", limit=120), buf.decode()
        os.write(master, b"status\n")
        assert _read_until(master, buf, b"EGP-RVS-STATUS OK"), buf.decode()
    text = buf.decode()
    after, before = text[stopped:], text[:stopped]
    until_ok = after[:after.index("EGP-RVS-DEM-FULL-TOF OK")]
    assert "PROGRESS" not in after, after
    # the prompt after the stop, and again under each EVENT printed at it (mode busy), none per PROGRESS
    assert until_ok.count("rvs> ") == 1 + until_ok.count("RVS EVENT"), until_ok
    assert after.count("EGP-RVS-DEM-FULL-TOF OK") == 1, after
    # the job's dozen PROGRESS lines came mostly after the stop: few are above it
    assert before.count("PROGRESS") < 6, before
