"""Every installed program, run as the user runs it (its console script, in a subprocess): a bad
option, command or input is one ``tool: message`` line on stderr and exit status 2, never a
usage block, a traceback or a blank line first (docs/TOOLS.md), and a message names options as
that command line spells them (``--cell``), not as the wire does (``-cell``)."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from support.marks import long_only

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"])
BIN = Path(sys.executable).parent


def _run(args: list[str], cwd: Path, stdin: str = "") -> tuple[int, str, str]:
    script = BIN / args[0]
    assert script.is_file(), f"{args[0]} is not installed beside {sys.executable}"
    p = subprocess.run([str(script), *args[1:]], cwd=cwd, input=stdin, capture_output=True, text=True, timeout=120)
    return p.returncode, p.stdout, p.stderr


def _one_line(rc: int, err: str, prog: str) -> str:
    assert rc == 2, (rc, err)
    assert err.count("\n") == 1 and err.startswith(f"{prog}: "), err
    return err


def test_every_console_script_is_covered() -> None:
    assert len(SCRIPTS) >= 14 and {"rvs-server", "rvs-client", "rvs-ptu", "rvs-prox"} <= set(SCRIPTS)


@pytest.mark.parametrize("script", SCRIPTS)
def test_an_unknown_option_is_one_line_and_exit_2(script: str, tmp_path: Path) -> None:
    rc, out, err = _run([script, "--no-such-option"], tmp_path)
    msg = _one_line(rc, err, script.split()[0])
    assert "--help lists the options" in msg, msg  # (a missing required argument may be named first)


# a bad command, value or input for each program: what a user mistypes in the third hour
BAD = [
    (["rvs-server", "--config", "/nonexistent_dir", "--port", "0"], "rvs-server: --config /nonexistent_dir: no such folder"),
    (["rvs-server", "--config", "{broken}", "--port", "0"], "rvs-server: {broken}/server.yaml: not valid YAML"),
    (["rvs-server", "--set", "bogus.key=1"], "rvs-server: --set 'bogus.key=1'"),
    (["rvs-ptu", "--backend", "serial", "--port", "/dev/nonexistent", "-c", "position"],
     "rvs-ptu: ptu: cannot open serial port /dev/nonexistent"),
    (["rvs-ptu", "--backend", "sim", "-c", "nosuchcmd"], "rvs-ptu: unknown command 'nosuchcmd'"),
    (["rvs-tof", "-c", "grab nosuch"], "rvs-tof: grab: argument type: invalid choice: 'nosuch'"),
    (["rvs-cam", "-c", "nosuchcmd"], "rvs-cam: unknown command 'nosuchcmd'"),
    (["rvs-prox", "{broken}/server.yaml"], "rvs-prox: server.yaml:2: not YAML"),
    (["rvs-prox", "dem", "--from", "/nonexistent"], "rvs-prox: /nonexistent: not a DEM job's folder"),
    (["rvs-prox", "dem", "--set", "cell=abc", "--validate"], "rvs-prox: --set cell takes a number"),
    (["rvs-dem-import", "{broken}/server.yaml", "--cell", "abc", "-o", "x_dem.tif"],
     "rvs-dem-import: --cell takes a number"),
    (["rvs-dem2hazard", "missing_dem.tif"], "rvs-dem2hazard: the following arguments are required: -o/--output"),
    (["rvs-client", "--host", "127.0.0.1"], "rvs-client: "),
    # a declared value is named as that command line or file spells it: the option, the --set
    # key, the YAML key; never the wire's -option (a range and an integer: the long suite's, the
    # same messages as rvs-ptu's range and the YAML typo's integer below)
    (["rvs-server", "--set", "navigate.tolerance=abc"], "rvs-server: --set navigate.tolerance takes a number"),
    pytest.param(["rvs-server", "--set", "navigate.tolerance=500"],
                 "rvs-server: --set navigate.tolerance is 500, out of range", marks=long_only()),
    pytest.param(["rvs-server", "--set", "drivers.ptu.baudrate=abc"],
                 "rvs-server: --set drivers.ptu.baudrate takes an integer", marks=long_only()),
    (["rvs-server", "--set", "hazard_start.warn_distance=0"],
     "rvs-server: --set hazard_start: stop_distance 0.5 must not exceed warn_distance 0"),
    (["rvs-server", "--config", "{typo}", "--port", "0"], "rvs-server: {typo}/drivers.yaml over config/drivers.yaml, section ptu: baudrate takes an integer"),
    (["rvs-ptu", "--time-scale", "-1", "-c", "position"], "rvs-ptu: --time-scale is -1, out of range"),
    (["rvs-ptu", "--config", "{typo}/drivers.yaml", "-c", "position"],
     "rvs-ptu: drivers.ptu: baudrate takes an integer"),
    (["rvs-tof", "--config", "{typo}/drivers.yaml", "-c", "help"], "rvs-tof: drivers.tof: integration is 999, out of range"),
    (["rvs-cam", "--config", "{typo}/drivers.yaml", "-c", "ids"], "rvs-cam: drivers.stereo: resolution takes low|"),
    (["rvs-dem-mosaik", "x.tif", "-o", "y.tif", "--cell", "200"], "rvs-dem-mosaik: --cell is 200, out of range"),
    (["rvs-dem-mosaik", "x.tif", "-o", "y.tif", "--cell", "-Infinity"], "rvs-dem-mosaik: --cell must be a finite number"),
    (["rvs-dem2hazard", "x.tif", "-o", "y", "--set", "window=abc"], "rvs-dem2hazard: --set window takes a number"),
    (["rvs-path-planner", "--hazard", "x.tif", "--slope", "x.tif", "--start", "0,0", "--goal", "1,1", "-o", "y",
      "--weight", "5"], "rvs-path-planner: --weight is 5, out of range"),
    pytest.param(["rvs-prox", "dem", "--set", "cell=5", "--validate"],
                 "rvs-prox: --set cell is 5, out of range", marks=long_only()),
    (["rvs-stereo", "x.tif", "x.tif", "--calib", "c.yaml", "--set", "scale=abc"],
     "rvs-stereo: stereo parameter scale takes a number, not 'abc'"),
]

WIRE_FLAG = re.compile(r"(^|[\s:'])-[a-z][a-z-]* (takes|is|must)")


@pytest.mark.parametrize(("argv", "message"), BAD, ids=[" ".join(getattr(b, "values", b)[0][:3]) for b in BAD])
def test_a_bad_command_or_input_is_one_line_and_exit_2(argv: list[str], message: str, tmp_path: Path) -> None:
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "server.yaml").write_text("port: [1,\n")
    typo = tmp_path / "typo"  # well-formed YAML with a value its key refuses
    typo.mkdir()
    (typo / "navigate.yaml").write_text("tolerance: abc\n")
    (typo / "drivers.yaml").write_text("ptu:\n  baudrate: abc\ntof:\n  integration: 999\nstereo:\n  resolution: huge\n")
    paths = {"broken": broken, "typo": typo}
    rc, out, err = _run([a.format(**paths) for a in argv], tmp_path)
    msg = _one_line(rc, err, argv[0])
    assert msg.startswith(message.format(**paths)), msg
    assert not WIRE_FLAG.search(msg), msg  # the wire's spelling of an option (-cell takes ...)
