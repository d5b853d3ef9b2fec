"""rvs-ptu: one-shot lines, error reporting, and a prompt command for every driver operation."""

from __future__ import annotations

import io

import pytest

from drivers.ptu import Ptu, create
from drivers.ptu.console import PtuConsole, main


def test_one_shot_move_prints_the_position(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["--backend", "sim", "--time-scale", "0", "--timeout", "0.5", "-c", "move 30 -10", "-c", "position"])
    out = capsys.readouterr().out.splitlines()
    assert rc == 0
    assert out == ["pan 29.983 deg, tilt -9.977 deg", "pan 29.983 deg, tilt -9.977 deg"]


def test_errors_are_printed_and_the_console_carries_on(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["--backend", "sim", "--time-scale", "0", "-c", "move 200 0; pan 10; speed 9000"])
    captured = capsys.readouterr()
    out, err = captured.out.splitlines(), captured.err.splitlines()
    assert rc == 1
    assert out == ["pan 9.977 deg, tilt 0.000 deg"]  # 194 positions; one-shot stdout holds only results
    assert err[0].startswith("open on ")  # start-up's open is a note
    assert err[1].startswith("error: ptu: pan 200 deg is beyond the pan maximum 158.91 deg")
    assert err[2] == "error: ptu: the PTU refused PS9000: Pan speed cannot exceed 2902 positions/sec"


def test_an_unknown_command_is_refused_before_anything_runs(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--backend", "sim", "--time-scale", "0", "-c", "move 20 0; frobnicate", "-c", "position"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err == "rvs-ptu: unknown command 'frobnicate'; 'help' lists the commands\n"


def test_serial_backend_missing_port(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["--backend", "serial", "--port", "/dev/does-not-exist-ptu", "-c", "position"])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("rvs-ptu: ptu: cannot open serial port /dev/does-not-exist-ptu")


@pytest.mark.parametrize(("argv", "message"), [
    (["--time-scale", "-1"], "rvs-ptu: --time-scale is -1, out of range"),
    (["--config", "{bad}"], "rvs-ptu: {bad}: not valid YAML: "),
    (["--config", "{missing}"], "rvs-ptu: {missing}: no such file"),
])
def test_bad_setup_is_one_error_line_and_exit_2(tmp_path, capsys: pytest.CaptureFixture[str], argv: list[str],
                                                message: str) -> None:
    paths = {"bad": tmp_path / "bad.yaml", "missing": tmp_path / "missing.yaml"}
    paths["bad"].write_text("ptu: [1\n")
    assert main(["--backend", "sim", *(a.format(**paths) for a in argv), "-c", "position"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and "Traceback" not in err
    assert err.count("\n") == 1 and err.startswith(message.format(**paths)), err


@pytest.fixture
def console() -> tuple[PtuConsole, io.StringIO, Ptu]:
    ptu = create({"backend": "sim", "time_scale": 0.0, "timeout": 0.3})
    out = io.StringIO()
    yield PtuConsole(ptu, stdout=out), out, ptu
    ptu.close()


def run(con: PtuConsole, out: io.StringIO, line: str) -> str:
    out.seek(0)
    out.truncate()
    con.onecmd(line)
    return out.getvalue()


def test_every_driver_operation_has_a_command(console: tuple[PtuConsole, io.StringIO, Ptu]) -> None:
    con, out, ptu = console
    commands = {name[3:] for name in dir(con) if name.startswith("do_")}
    assert {"move", "pan", "tilt", "wait", "position", "limits", "speed", "accel", "halt", "reset",
            "status", "power", "check", "raw", "reinit", "open", "close", "fault", "firmware"} <= commands
    assert run(con, out, "raw PP") == "* 0\n"
    assert run(con, out, "speed 1500 800") == "speed pan 1500 tilt 800 positions/s\n"
    assert run(con, out, "accel 3000") == "acceleration pan 3000 tilt 3000 positions/s^2\n"
    assert "pan: -158.914 .. 158.914 deg (positions -3090 .. 3090" in run(con, out, "limits")
    assert run(con, out, "power") == "supply 30 V, temperatures 86 F\n"
    assert run(con, out, "tilt -20") == "pan 0.000 deg, tilt -20.006 deg\n"  # -389 positions
    assert run(con, out, "move 10 5 nowait") == "pan 9.977 deg, tilt 4.989 deg\n"
    assert run(con, out, "wait") == "pan 9.977 deg, tilt 4.989 deg\n"
    assert run(con, out, "halt") == "halted at pan 9.977 deg, tilt 4.989 deg\n"
    assert run(con, out, "reset") == "reset done, pan 0.000 deg, tilt 0.000 deg\n"
    assert "backend: sim" in run(con, out, "status")
    assert "voltage_v: 30.0" in run(con, out, "check")
    assert "PTU-D46" in run(con, out, "firmware")


def test_faults_and_recovery_from_the_prompt(console: tuple[PtuConsole, io.StringIO, Ptu]) -> None:
    con, out, ptu = console
    assert run(con, out, "open").startswith("open on /dev/")
    assert run(con, out, "fault silent").startswith("fault silent injected")
    assert run(con, out, "position").startswith("error: ptu: no reply to PP within 0.3s")
    assert run(con, out, "fault none").startswith("fault none injected")
    assert run(con, out, "reinit").startswith("reinitialised on /dev/")
    assert run(con, out, "position") == "pan 0.000 deg, tilt 0.000 deg\n"
    assert run(con, out, "move 1").startswith("error: usage: move PAN TILT")
    assert run(con, out, "raw").startswith("error: usage: raw CMD")
    assert run(con, out, "pan nan").startswith("error: finite numbers expected; usage: pan DEG")
    assert run(con, out, "move x 1").startswith("error: numbers expected; usage: move PAN TILT")
    assert con.onecmd("quit") is True
