"""rvs-replay: the shipped scripts against fresh servers, the matching rules on canned lines,
and --record turning volatile values into patterns."""

from __future__ import annotations

import re
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest
from support.marks import long_test
from support.server import FAST

from rvs_server import __version__
from rvs_server.client import replay
from rvs_server.client.replay import ScriptError, Step, check, parse_script, pattern_for
from rvs_server.client.session import Line, ServerProcess

REPLAYS = sorted((Path(__file__).resolve().parents[2] / "replays").glob("*.rvs"))
SUMMARY = re.compile(r"(\d+) passed, (\d+) failed")
SERVER = ["--server", *(f"--server-arg={a}" for a in FAST)]


@pytest.fixture(scope="module")
def server() -> Iterator[ServerProcess]:
    with ServerProcess(extra_args=FAST) as srv:
        yield srv


def summary(out: str) -> tuple[int, int]:
    last = out.strip().splitlines()[-1]
    m = SUMMARY.fullmatch(last)
    assert m, f"last line is not 'N passed, N failed': {last!r}"
    return int(m.group(1)), int(m.group(2))


def lines(*texts: str, mine: bool = True) -> list[Line]:
    return [Line(t, mine) for t in texts]


def patterns(*sources: str) -> list[re.Pattern[str]]:
    return [re.compile(s) for s in sources]


# ---------------------------------------------------------------------- the shipped scripts


def test_replay_scripts_are_shipped() -> None:
    assert {p.name for p in REPLAYS} >= {"system.rvs", "modes.rvs"}


@pytest.mark.parametrize("script", REPLAYS, ids=lambda p: p.name)
def test_shipped_script_passes_against_a_fresh_server(script: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = replay.main([*SERVER, str(script)])
    out = capsys.readouterr().out
    steps = [i for i in replay.load(script) if isinstance(i, Step)]
    assert (rc, summary(out)) == (0, (len(steps), 0)), out
    assert not any(step.request.split()[0] == "quit" for step in steps)


# ---------------------------------------------------------------------- matching on canned lines


def test_progress_and_event_lines_may_be_skipped() -> None:
    got = lines("EGP-RVS-RESET ACK job=4", "EGP-RVS-RESET PROGRESS job=4 done=1 total=8 message=x",
                "EGP-RVS-RESET OK job=4 devices=ptu:ok")
    got.insert(1, Line("RVS EVENT kind=mode mode=busy", mine=False))
    assert check(patterns(r"EGP-RVS-RESET ACK job=\d+", r"EGP-RVS-RESET OK job=\d+ devices=\S+"), got) is None


def test_expected_events_and_progress_are_matched_in_order() -> None:
    got = [Line("EGP-RVS-SLEEP ACK job=1"), Line("RVS EVENT kind=mode mode=sleep", mine=False),
           Line("EGP-RVS-SLEEP OK job=1 slept=0.1")]
    assert check(patterns("EGP-RVS-SLEEP ACK .*", "RVS EVENT kind=mode mode=sleep", "EGP-RVS-SLEEP OK .*"), got) is None
    # ...and an expected EVENT that never came leaves an expectation when the final line arrives
    failure = check(patterns("EGP-RVS-SLEEP ACK .*", "RVS EVENT kind=mode mode=busy", "EGP-RVS-SLEEP OK .*"), got)
    assert failure is not None and "does not match" in failure


def test_a_mismatching_final_line_fails() -> None:
    failure = check(patterns("EGP-RVS-STATUS OK mode=ready .*"), lines("EGP-RVS-STATUS OK mode=break job=none"))
    assert failure is not None and "mode=break" in failure


def test_matching_is_a_full_match() -> None:
    assert check(patterns("EGP-RVS-STATUS OK"), lines("EGP-RVS-STATUS OK mode=ready")) is not None


def test_an_unexpected_ack_or_ok_fails() -> None:
    failure = check(patterns(r"EGP-RVS-SLEEP ACK job=\d+"), lines("EGP-RVS-SLEEP ACK job=1", "EGP-RVS-SLEEP OK job=1"))
    assert failure is not None and "no expectation left" in failure


def test_final_line_with_expectations_left_fails() -> None:
    failure = check(patterns("X ACK job=1", "X OK job=1"), lines("X ERROR code=E_BUSY job=9 message=m"))
    assert failure is not None
    failure = check(patterns("X OK", "never"), lines("X OK"))
    assert failure is not None and "1 expectation(s) left" in failure


def test_timeout_and_closed_connection_fail() -> None:
    assert check([], lines("X ACK job=1"), "timeout") is not None
    assert check([], [], "closed") is not None
    assert check([], lines("X OK")) is None  # no expectations: any final line will do


def test_unrelated_lines_are_skipped_even_if_final_looking() -> None:
    got = [Line("EGP-RVS-SLEEP ERROR tag=c3 job=1 code=E_INTERRUPTED message=m", mine=False), Line("EGP-RVS-BREAK OK")]
    assert check(patterns("EGP-RVS-BREAK OK"), got) is None


# ---------------------------------------------------------------------- script syntax


def test_a_late_line_of_a_timed_out_step_is_matched_with_its_tag() -> None:
    """The session shows a given-up request's late lines without their automatic tag; the
    replay still matches them as they came, so one never passes for the next step's reply."""
    late = Line("EGP-RVS-SLEEP OK tag=r1 job=1 slept=60.0", False, "EGP-RVS-SLEEP OK job=1 slept=60.0")
    got = [late, *lines("EGP-RVS-SLEEP ACK job=2")]
    failure = check(patterns(r"EGP-RVS-SLEEP OK job=\d+ slept=[0-9.]+"), got)
    assert failure is not None and "does not match: EGP-RVS-SLEEP ACK job=2" in failure


def test_parse_script_keeps_order_and_drops_requests_without_reply() -> None:
    items = parse_script("# head\n> status\n< A\n<B\n\n> # nothing\n< ignored\n>  version  \n", "s.rvs")
    steps = [i for i in items if isinstance(i, Step)]
    assert [(s.request, s.expect, s.lineno) for s in steps] == [("status", ["A", "B"], 2), ("version", [], 8)]
    assert steps[0].where == "s.rvs:2"
    assert items[0] == "# head"


@pytest.mark.parametrize("text", ["< before any request\n", "> status\n< (unclosed\n", "> status\nstray words\n"])
def test_bad_scripts_are_script_errors(text: str) -> None:
    with pytest.raises(ScriptError, match=r"s\.rvs:\d+"):
        parse_script(text, "s.rvs")


def test_a_bad_script_is_exit_status_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.rvs"
    bad.write_text("> status\n< (\n")
    assert replay.main(["--port", "1", str(bad)]) == 2
    assert "bad.rvs:2" in capsys.readouterr().err


# ---------------------------------------------------------------------- against a live server


def test_failures_show_expected_and_actual_lines(
    server: ServerProcess, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    script = tmp_path / "mixed.rvs"
    script.write_text(
        "> status\n< EGP-RVS-STATUS OK mode=busy .*\n"
        "> version\n< EGP-RVS-VERSION OK .*\n"
        "> sleep -seconds 0\n< EGP-RVS-SLEEP ACK job=\\d+\n"
    )
    rc = replay.main(["--port", str(server.port), str(script)])
    out = capsys.readouterr().out
    assert rc == 1 and summary(out) == (1, 2)
    assert f"FAIL {script}:1: > status" in out and f"FAIL {script}:5: > sleep -seconds 0" in out
    assert "< EGP-RVS-STATUS OK mode=busy .*" in out
    assert re.search(r"^    EGP-RVS-STATUS OK mode=ready ", out, re.M)  # actual, auto tag removed
    assert "tag=r" not in out


def test_shipped_scripts_pass_against_a_running_server_with_a_recovery_set(
    server: ServerProcess, capsys: pytest.CaptureFixture[str]
) -> None:
    """``rvs-replay --port`` against a server that was used before: modes.rvs leaves a recovery
    set (its break) and system.rvs a pose, and the scripts run again over both."""
    scripts = [str(p) for p in REPLAYS if p.name in ("modes.rvs", "system.rvs")]
    rc = replay.main(["--port", str(server.port), *scripts, *scripts])
    out, err = capsys.readouterr()
    steps = sum(isinstance(i, Step) for p in scripts for i in replay.load(Path(p)))
    assert (rc, summary(out)) == (0, (2 * steps, 0)), out
    assert "not ready" not in err


def test_a_server_not_in_ready_mode_is_named_and_record_needs_its_folder(
    server: ServerProcess, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    script = tmp_path / "s.rvs"
    script.write_text("> version\n")
    assert replay.main(["--port", str(server.port), "--record", str(tmp_path / "no" / "r.rvs"), str(script)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rvs-replay: --record ") and "no folder" in err and "Traceback" not in err
    script.write_text("> standby\n> version\n")
    assert replay.main(["--port", str(server.port), str(script)]) == 0
    script.write_text("> continue\n")
    assert replay.main(["--port", str(server.port), str(script)]) == 0
    assert "the server is in standby mode, not ready" in capsys.readouterr().err


def test_without_a_named_server_nothing_is_contacted(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    script = tmp_path / "s.rvs"
    script.write_text("> version\n")
    with pytest.raises(SystemExit) as exc:
        replay.main([str(script)])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "say which server" in err and "--server" in err and "--host/--port" in err
    assert "passed" not in err and "cannot talk to" not in err
    with pytest.raises(SystemExit) as exc:
        replay.main(["--server", "--port", "7070", str(script)])
    assert exc.value.code == 2 and "drop --host/--port" in capsys.readouterr().err


def test_stderr_names_the_server_it_talks_to(
    server: ServerProcess, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    script = tmp_path / "s.rvs"
    script.write_text("> version\n")
    assert replay.main(["--port", str(server.port), str(script)]) == 0
    err = capsys.readouterr().err
    assert f"the running server at 127.0.0.1:{server.port} (rvs/{__version__}, protocol 1, mode ready)" in err
    assert replay.main([*SERVER, str(script)]) == 0
    err = capsys.readouterr().err
    assert re.search(rf"a fresh simulated server at 127\.0\.0\.1:(\d+) \(rvs/{re.escape(__version__)},", err)
    assert f":{server.port} " not in err


def test_no_server_is_exit_status_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    script = tmp_path / "s.rvs"
    script.write_text("> status\n")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert replay.main(["--port", str(port), str(script)]) == 2
    assert "cannot talk to" in capsys.readouterr().err


# ---------------------------------------------------------------------- recording


@pytest.mark.parametrize(
    ("line", "pattern", "other_run"),
    [
        ("EGP-RVS-SLEEP ACK job=12", r"EGP-RVS-SLEEP ACK job=\d+", "EGP-RVS-SLEEP ACK job=3"),
        ("EGP-RVS-SLEEP OK tag=x job=2 slept=0.101", r"EGP-RVS-SLEEP OK tag=x job=\d+ slept=[0-9.]+",
         "EGP-RVS-SLEEP OK tag=x job=7 slept=0.100"),
        ("EGP-RVS-BREAK OK interrupted=3 recovery=recovery/20261121T043000_123456Z",
         r"EGP-RVS-BREAK OK interrupted=\d+ recovery=recovery/\d{8}T\d{6}(?:_\d+)?Z?",
         "EGP-RVS-BREAK OK interrupted=9 recovery=recovery/20270101T000000_000001Z"),
        ("EGP-RVS-BREAK OK interrupted=none recovery=recovery/20261121T043000_123456Z",
         r"EGP-RVS-BREAK OK interrupted=none recovery=recovery/\d{8}T\d{6}(?:_\d+)?Z?", None),
        ("EGP-RVS-LOGBOOK OK file=shared/rvs_20261121T043032.log",
         r"EGP-RVS-LOGBOOK OK file=shared/rvs_\d{8}T\d{6}(?:_\d+)?Z?\.log", "EGP-RVS-LOGBOOK OK file=shared/rvs_20200101T010101.log"),
        ("EGP-RVS-VERSION OK server=rvs/0.1.0 python=3.11.7", r"EGP-RVS-VERSION OK server=rvs/0\.1\.0 python=\S+",
         "EGP-RVS-VERSION OK server=rvs/0.1.0 python=3.12.1"),
        ('EGP-RVS-SLEEP ERROR job=1 code=E_INTERRUPTED message="sleep job 1 was interrupted (at 2026-11-21T04:30:00.5Z)"',
         r'EGP-RVS-SLEEP ERROR job=\d+ code=E_INTERRUPTED message="sleep job \d+ was interrupted \(at '
         r'\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}(?:\.\d+)?(?:Z|[+-]\d{2}:?\d{2})?\)"',
         'EGP-RVS-SLEEP ERROR job=5 code=E_INTERRUPTED message="sleep job 5 was interrupted (at 2027-01-01T00:00:00Z)"'),
        ("EGP-RVS-STATUS OK mode=ready job=none devices=ptu:ok,tof:ok clients=3 uptime=12.5",
         r"EGP-RVS-STATUS OK mode=ready job=none devices=\S+ clients=\d+ uptime=[0-9.]+",
         "EGP-RVS-STATUS OK mode=ready job=none devices=ptu:ok clients=1 uptime=0.1"),
        ('{"module":"EGP-RVS-SLEEP","status":"OK","job":4,"slept":0.25}',
         r'\{"module":"EGP-RVS-SLEEP","status":"OK","job":\d+,"slept":[0-9.eE+-]+\}',
         '{"module":"EGP-RVS-SLEEP","status":"OK","job":40,"slept":1.5}'),
    ],
)
def test_record_turns_volatile_values_into_patterns(line: str, pattern: str, other_run: str | None) -> None:
    assert pattern_for(line) == pattern
    assert re.fullmatch(pattern, line)
    if other_run is not None:
        assert re.fullmatch(pattern, other_run)


def test_record_escapes_everything_else() -> None:
    line = 'EGP-RVS-HELP OK usage="sleep [-seconds number]" text="a.b (c)*+?"'
    pattern = pattern_for(line)
    assert re.fullmatch(pattern, line)
    assert not re.fullmatch(pattern, line.replace("a.b", "axb"))


@long_test  # the default run's time; the shipped replay scripts pass against a fresh server there
def test_record_then_replay_round_trip(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    requests = tmp_path / "requests.txt"
    requests.write_text("# a plain file of requests\nstatus\n\nsleep -seconds 0\nfrobnicate\nbreak\ncontinue\n")
    script = tmp_path / "recorded.rvs"
    rc = replay.main([*SERVER, "--record", str(script), str(requests)])
    out = capsys.readouterr().out
    assert rc == 0 and summary(out) == (5, 0)
    text = script.read_text()
    assert text.startswith("# a plain file of requests\n> status\n< EGP-RVS-STATUS OK mode=ready")
    assert r"< EGP-RVS-SLEEP ACK job=\d+" in text and r"< EGP-RVS-SLEEP OK job=\d+ slept=[0-9.]+" in text
    assert r"recovery=recovery/\d{8}T\d{6}" in text
    assert "EVENT" not in text and "PROGRESS" not in text and "tag=" not in text
    assert re.search(r"job=\d(?!\d|\+)", text) is None  # no literal job ids left
    # the recorded script passes against another fresh server
    rc = replay.main([*SERVER, str(script)])
    assert (rc, summary(capsys.readouterr().out)) == (0, (5, 0))
