"""What users record replays: a run of each kind recorded by a real server over TCP (``record
-start`` / ``record -stop``), then the real ``rvs-replay --mcap`` CLI run on it as a subprocess.
A replay of a recording reproduces it (exit 0, every reply and map layer the same), or says in
one line why it cannot (exit 2)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
from support.marks import long_test
from support.mcap import decoded
from support.server import ServerThread, wait_for

from rvs_server.monitors import Monitor

DEM = "dem-full-tof -range -30,30,-40,-20 -overlap 0.1 -name rec"  # two views


def record(data: Path, steps: list[str], before: tuple[str, ...] = (), profile: str = "foxglove",
           sets: tuple[str, ...] = ()) -> dict[str, dict[str, str]]:
    """Run ``before``, then record ``steps`` (``wait:FIELD>=N`` polls status until it holds);
    the final replies' fields by command."""
    srv = ServerThread(data, list(sets)).start()
    replies: dict[str, dict[str, str]] = {}
    try:
        c = srv.client()
        for line in before:
            assert c.request(line, timeout=120).status == "OK", line
        assert c.request(f"record -start -name run -profile {profile}").status == "OK"
        for line in steps:
            if line.startswith("wait:"):
                field, least = line[5:].split(">=")
                # each poll is a recorded request the replay sends again: a few, not hundreds
                assert wait_for(lambda c=c, f=field, n=int(least): int(c.request("status").fields.get(f, -1)) >= n,
                                interval=0.25)
                continue
            reply = c.request(line, timeout=120)
            assert reply.status == "OK", (line, reply)
            replies[line.split()[0]] = reply.fields
        assert c.request("record -stop").status == "OK"
        c.close()
    finally:
        srv.stop()
    return replies


def rvs_replay(*args: str | Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rvs_server.client.replay", *map(str, args)],
                          capture_output=True, text=True, timeout=600)


def assert_matches(out: subprocess.CompletedProcess[str], requests: int, layers: int | None = None) -> None:
    assert out.returncode == 0, out.stdout + out.stderr
    assert "MISMATCH" not in out.stdout, out.stdout
    what = "replies" if layers is None else f"replies and {layers} map layers"
    assert f"{requests} requests replayed from " in out.stdout and f"{what} match (0 mismatches)" in out.stdout, \
        out.stdout


def test_a_console_click_navigate_with_auto_replays(tmp_path: Path) -> None:
    # the console's click-navigate line, with its "-auto" box ticked
    nav = "navigate -goal 0.60,0.00 -sensor tof -tolerance 0.3 -auto true -loop scan -scan-plan circle"
    # a narrower scan than the default (fewer views: a smaller recording), replayed with it
    got = record(tmp_path / "rec", [nav, "status"], sets=("navigate.range=-40,40,-45,-20",))
    assert got["navigate"]["reached"] == "true" and got["navigate"]["pose_source"] == "odometry"
    out = rvs_replay("--mcap", tmp_path / "rec" / "recordings" / "run.mcap", "--products")
    assert_matches(out, 2, layers=12)  # the scan's DEM, every layer, cell for cell


@long_test  # 15-25 s of monitor cycles recorded and replayed twice: CI's long suite runs it
def test_monitor_summaries_replay_as_recorded_and_recorded_timing_takes_the_recorded_time(tmp_path: Path) -> None:
    steps = ["hazard-start", "wait:hazard_cycles>=2", "hazard-stop",  # their default periods: 0.3 s, none
             "track3d-start", "wait:track_cycles>=2", "track3d-stop"]
    got = record(tmp_path / "rec", steps)
    assert int(got["hazard-stop"]["cycles"]) >= 2 and got["hazard-stop"]["level"] != "none", got
    assert int(got["track3d-stop"]["cycles"]) >= 2, got
    path = tmp_path / "rec" / "recordings" / "run.mcap"
    fast = rvs_replay("--mcap", path, "--data", tmp_path / "fast")  # each cycle as soon as the one before ended
    events = [m["line"] for topic, _, m in decoded(tmp_path / "fast" / "recordings" / "replay.mcap")
              if topic == "/rvs/wire" and m["dir"] == "event"]
    assert fast.returncode == 0 and "replies match (0 mismatches)" in fast.stdout, (fast.stdout, fast.stderr, events)
    out = rvs_replay("--mcap", path, "--timing", "recorded", "--data", tmp_path / "replay")
    assert out.returncode == 0 and "MISMATCH" not in out.stdout, out.stdout + out.stderr
    assert "replies match (0 mismatches)" in out.stdout, out.stdout  # the status polls are replayed too

    # with recorded timing each request goes no earlier after the recording's start than it did
    def since_start(p: Path) -> int:
        from drivers.replay import Recording

        t = [t for topic, t, m in decoded(p) if topic == "/rvs/wire" and m["dir"] == "request"
             and not m["line"].startswith("record")]
        return t[-1] - (Recording(p).start_ns or 0)

    assert since_start(tmp_path / "replay" / "recordings" / "replay.mcap") >= since_start(path) > 1_000_000_000


@long_test  # a recording and its replay, 13-28 s on a loaded machine: CI's long suite runs it
def test_a_monitor_whose_stop_came_late_replays_the_cycles_it_made_meanwhile(tmp_path: Path,
                                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    # as on a loaded machine: the stop reaches the monitor a while after the request came in, and
    # the cycles the monitor makes meanwhile are in the count the stop answers
    stop = Monitor.stop

    def late(self: Monitor, timeout: float = 5.0) -> None:
        time.sleep(0.4)
        stop(self, timeout)

    monkeypatch.setattr(Monitor, "stop", late)
    got = record(tmp_path / "rec", ["track3d-start", "wait:track_cycles>=2", "track3d-stop"])
    monkeypatch.undo()
    path = tmp_path / "rec" / "recordings" / "run.mcap"
    messages = decoded(path)
    wire = [(t, m["line"]) for topic, t, m in messages if topic == "/rvs/wire"]
    asked = next(t for t, line in wire if line == "track3d-stop")
    answered = next(t for t, line in wire if line.startswith("EGP-RVS-TRACK3D-STOP OK"))
    frames = [t for topic, t, m in messages if topic == "/raw/calls" and m["device"] == "tof"]
    assert sum(asked < t < answered for t in frames) >= 2, (asked, answered, frames)  # the case in hand
    out = rvs_replay("--mcap", path)  # its stop's reply, cycles and all, is compared
    assert out.returncode == 0 and "replies match (0 mismatches)" in out.stdout, (got, out.stdout + out.stderr)


@long_test  # 15-30 s of DEM and replay; the console's recording replays by default
def test_a_recording_started_after_a_dem_replays_from_that_dem(tmp_path: Path) -> None:
    # a move that reaches past the rover's unseen footprint into the map: the verdict reads its cells
    got = record(tmp_path / "rec", ["check-move -dx 2"], before=(DEM,))
    assert int(got["check-move"]["unknown_cells"]) < int(got["check-move"]["cells"]), got
    out = rvs_replay("--mcap", tmp_path / "rec" / "recordings" / "run.mcap", "--products")
    assert_matches(out, 1, layers=0)  # no map made during the recording: nothing to compare, no mismatch


@long_test  # a second bit-exact replay (away from the origin), 10-20 s; the others run by default
def test_a_recording_away_from_the_origin_replays_bit_exact(tmp_path: Path) -> None:
    # the rover stands away from the origin on the ground a DEM made before the recording shows
    # (its height places the new scan's points); the new DEM must come back cell for cell
    record(tmp_path / "rec", [DEM], before=(DEM, "pose -x 0.8 -y 0.5 -heading 32.00538320808349"))
    out = rvs_replay("--mcap", tmp_path / "rec" / "recordings" / "run.mcap", "--products")
    assert_matches(out, 1, layers=12)


def test_a_ros2_recording_is_refused_in_one_line(tmp_path: Path) -> None:
    record(tmp_path / "rec", ["status"], profile="ros2")
    bag = tmp_path / "rec" / "recordings" / "run"
    for given in (bag, bag / "run_0.mcap"):  # the rosbag2 directory or the MCAP file in it
        out = rvs_replay("--mcap", given)
        assert out.returncode == 2, out.stdout + out.stderr
        assert out.stdout == "" and len(out.stderr.strip().splitlines()) == 1, out.stderr
        assert "ros2-profile recording" in out.stderr and "-profile foxglove" in out.stderr, out.stderr

