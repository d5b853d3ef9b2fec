"""What a rover team hits in its first hour, each through a real TCP socket: break after
every pose-setting job, pose reports during navigate, telnet's Ctrl-C, exit, progress lines a
progress bar can use, refusals before the ACK, help as typed on the wire, modes."""

from __future__ import annotations

import socket
import time
from collections import defaultdict
from pathlib import Path

import pytest
import yaml
from support.marks import long_test
from support.server import LineClient, ServerThread, waiting_event

from rvs_server.protocol import Reply

# ------------------------------------------------------------------ 1. break after pose-setting jobs


def _assert_complete_recovery(srv: ServerThread, r: Reply) -> dict:
    assert r.status == "OK", r.fields
    folder = srv.data / r.fields["recovery"]
    manifest = yaml.safe_load((folder / "manifest.yaml").read_text())
    assert all(type(manifest["pose"][k]) is float for k in ("x", "y", "heading")), manifest["pose"]
    assert not list((srv.data / "recovery").glob(".*")), "a temp folder was left behind"
    return manifest


def _orient_twice(srv: ServerThread, c: LineClient) -> None:
    assert c.request("orient -sensor stereo", timeout=120).status == "OK"
    srv.app.world.move_rover(0.5, 0.0, 0.0)
    r = c.request("orient -sensor stereo", timeout=120)
    assert r.status == "OK" and float(r.fields["x"]) > 0.3, r.fields


# navigate's legs scan 120 degrees towards the goals below, not 360: these tests are about the wait,
# the pose and the progress lines, which a narrower scan leaves the same (and 3x cheaper)
NARROW = "navigate.range=-90,30,-50,-10"

SETTERS = {
    "navigate -auto": lambda srv, c: c.request("navigate -goal 1.2,0 -auto -loop scan -scan-plan circle -name brk", timeout=300),
    "orient": _orient_twice,
    "sim move-rover": lambda srv, c: c.request("sim move-rover -dx 0.3 -dyaw 10"),
    "pose": lambda srv, c: c.request("pose -x 1.25 -y -0.5 -heading 12.5"),
}


@pytest.mark.parametrize("setter", list(SETTERS))
def test_break_after_every_job_that_sets_the_pose_writes_a_complete_recovery_set(server_factory, setter) -> None:
    srv = server_factory(["server.scene=office", NARROW])
    c, watcher = srv.client(), srv.client()
    SETTERS[setter](srv, c)
    pose = srv.app.pose
    manifest = _assert_complete_recovery(srv, c.request("break"))
    assert manifest["pose"] == pytest.approx({"x": pose.x, "y": pose.y, "heading": pose.heading})
    modes = [r.fields["mode"] for r in watcher.lines_before_status() if r.fields.get("kind") == "mode"]
    assert modes[-1] == "break" and "ready" not in modes[modes.index("break"):]
    assert c.request("status").fields["mode"] == "break"
    r = c.request("recover", timeout=60)
    assert r.status == "OK" and r.fields["pose"].split(",")[0] == f"{pose.x:.3f}"


def test_a_recovery_set_that_cannot_be_written_leaves_no_temp_folder_and_still_breaks(
        server, client, monkeypatch) -> None:
    import rvs_server.maps as maps_module

    def full_disk(path: Path, data: object) -> Path:
        raise OSError(28, "No space left on device")

    client.send("@s sleep -seconds 30")
    job = client.reply().fields["job"]
    monkeypatch.setattr(maps_module, "write_yaml_atomic", full_disk)
    other = server.client()
    r = other.request("break")
    assert r.status == "ERROR" and r.fields["code"] == "E_IO"
    assert "break mode" in r.fields["message"] and "No space left" in r.fields["message"]
    assert client.until_final(job=job)[-1].fields["code"] == "E_INTERRUPTED"
    assert not list((server.data / "recovery").iterdir())
    assert other.request("status").fields["mode"] == "break"


def test_a_temp_folder_a_crash_left_is_removed_at_start(server_factory, tmp_path: Path) -> None:
    data = tmp_path / "d"
    stray = data / "recovery" / ".20260101T000000_000000Z.tmp"
    (stray / "maps").mkdir(parents=True)
    (stray / "maps" / "x_dem.tif").write_bytes(b"half")
    srv = server_factory(data=data)
    assert not stray.exists()
    assert srv.client().request("status").fields["recovery"] == "none"


# ------------------------------------------------------------------ 2. pose reports during navigate


def test_a_streamed_pose_ends_the_wait_only_once_it_holds_still(server_factory) -> None:
    """A GNC streams its pose while it drives: passing the leg's end, or coming within the goal's
    tolerance of it, while moving does not end the wait; the pose holding still does."""
    srv = server_factory(["server.scene=office", NARROW, "navigate.pose_settle=0.5"])
    c, gnc = srv.client(), srv.client()
    job = c.start_job("navigate -goal 1.5,-1.2 -loop scan -scan-plan circle -name stream")
    event = waiting_event(gnc)
    assert event.fields["job"] == job and event.fields["leg"] == "1"
    wps = [float(v) for v in event.fields["waypoints"].split(",")]
    end = wps[-3:-1]  # x,y,heading triples
    # the GNC streams its creeping pose at 20 Hz while it drives
    for i in range(30):
        assert gnc.request(f"pose -x {0.01 * i:.3f} -y 0 -heading 0").status == "OK"
        time.sleep(0.05)
    # ... then drives through the leg's end and on, each report 2 cm from the last
    for k in range(-10, 11):
        x, y = end[0] + 0.02 * k, end[1]
        assert gnc.request(f"pose -x {x:.3f} -y {y:.3f} -heading 0").status == "OK"
        time.sleep(0.05)
    st = gnc.request("status")
    assert st.fields["job"] == job and st.fields["phase"] == "drive", st.fields
    assert srv.app.jobs.current is not None and srv.app.jobs.current.context == {"leg": 1}
    # it comes back to the leg's end and stands there: the same pose, reported twice, holds
    srv.app.world.set_rover_pose(end[0], end[1], 0.0)
    for _ in range(2):
        assert gnc.request(f"pose -x {end[0]} -y {end[1]} -heading 0").status == "OK"
    final = c.until_final(job=job, timeout=300)[-1]
    assert final.status == "OK" and final.fields["reached"] == "true", final.fields
    assert abs(float(final.fields["x"]) - end[0]) < 1e-3


@long_test  # 7-10 s of scans: CI's long suite runs it; the streamed pose ending the wait runs by default
def test_stopped_ends_the_wait_and_two_rescans_from_one_spot_are_e_data(server_factory) -> None:
    srv = server_factory(["server.scene=office", NARROW])
    c, gnc = srv.client(), srv.client()
    job = c.start_job("navigate -goal 1.5,-1.2 -loop scan -scan-plan circle -name stuck")
    legs = []
    for _ in range(3):  # the GNC gives up at once, three times, without moving
        legs.append(waiting_event(gnc).fields["leg"])
        assert gnc.request("pose -stopped true").fields["stopped"] == "true"
        if len(legs) == 2:
            break
    final = c.until_final(job=job, timeout=300)[-1]
    assert legs == ["1", "2"]
    assert final.status == "ERROR" and final.fields["code"] == "E_DATA"
    assert "no progress" in final.fields["message"] and "(0.00, 0.00)" in final.fields["message"]
    # the failed navigate still leaves the track the rover drove (here: stopped where it started)
    assert "the track so far: nav/stuck_track.csv" in final.fields["message"]
    rows = (srv.data / "nav" / "stuck_track.csv").read_text().splitlines()
    assert rows[0] == "x,y,heading" and len(rows) >= 3 and set(rows[1:]) == {"0.0000,0.0000,0.00"}


# ------------------------------------------------------------------ 3. telnet's Ctrl-C, exit


IAC_IP_DO_TM = b"\xff\xf4\xff\xfd\x06"
WILL_TM = b"\xff\xfb\x06"


def _read_until(sock: socket.socket, needle: bytes, timeout: float = 10.0) -> bytes:
    sock.settimeout(timeout)
    buf = b""
    while needle not in buf:
        chunk = sock.recv(65536)
        if not chunk:
            raise ConnectionError(f"closed before {needle!r}; got {buf!r}")
        buf += chunk
    return buf


def test_telnet_ctrl_c_breaks_this_connections_job_and_answers_the_timing_mark(server) -> None:
    telnet = socket.create_connection(("127.0.0.1", server.port))
    _read_until(telnet, b"\r\n")  # greeting
    telnet.sendall(b"sleep -seconds 30\r\n")
    _read_until(telnet, b"ACK")
    telnet.sendall(IAC_IP_DO_TM)  # what telnet sends on Ctrl-C
    raw = _read_until(telnet, WILL_TM)
    while b"EGP-RVS-BREAK OK" not in raw or b"E_INTERRUPTED" not in raw:
        raw += _read_until(telnet, b"\n")
    # (one recv may bring the mark and the lines after it: split at the mark, not at the read)
    got, after = raw[: raw.index(WILL_TM)], raw[raw.index(WILL_TM) + len(WILL_TM):]
    # nothing telnet must see comes before the timing mark's answer: it discards all of that
    assert b"EGP-RVS-BREAK" not in got and b"E_INTERRUPTED" not in got
    text = after.decode()
    assert "EGP-RVS-SLEEP ERROR" in text and "interrupted=" in text
    c = server.client()
    assert c.request("status").fields["mode"] == "break"
    telnet.close()


def test_telnet_ctrl_c_leaves_other_connections_jobs_alone(server) -> None:
    owner, telnet = server.client(), server.client()
    job = owner.start_job("sleep -seconds 0.8")
    telnet.send(b"status\r\n" + IAC_IP_DO_TM)
    raw = _read_until(telnet.sock, WILL_TM)
    assert raw.index(b"EGP-RVS-STATUS OK") < raw.index(WILL_TM)  # the mark after the input before it
    final = owner.until_final(job=job)[-1]
    assert final.status == "OK"  # not interrupted
    assert owner.request("status").fields["mode"] == "ready"


def test_exit_and_bye_close_only_this_connection(server) -> None:
    other = server.client()
    for word in ("exit", "bye"):
        c = server.client()
        c.send(f"{word}\nversion\n")
        r = c.reply()
        assert (r.module, r.status) == ("EGP-RVS-EXIT", "OK")
        with pytest.raises(ConnectionError):
            c.line()  # closed; the version after it was not answered
    assert other.request("version").status == "OK"
    h = other.request("help quit").fields["text"]
    assert "stop the server" in h and "exit" in h


# ------------------------------------------------------------------ 4. progress lines


def _check_progress(lines: list[Reply]) -> dict[tuple[str, str], list[tuple[int, int]]]:
    phases: dict[tuple[str, str], list[tuple[int, int]]] = defaultdict(list)
    order: list[tuple[str, str]] = []
    for r in lines:
        if r.status != "PROGRESS":
            continue
        key = (r.fields.get("phase", ""), r.fields.get("leg", ""))
        if not order or order[-1] != key:
            assert key not in order, f"phase {key} came back after {order[-1]}"
            order.append(key)
        phases[key].append((int(r.fields["done"]), int(r.fields["total"])))
    for key, seq in phases.items():
        totals = {t for _, t in seq}
        dones = [d for d, _ in seq]
        assert len(totals) == 1, f"total changed within {key}: {seq}"
        assert all(b > a for a, b in zip(dones, dones[1:], strict=False)), f"done did not grow within {key}: {seq}"
        assert 0 <= dones[0] and dones[-1] <= seq[0][1]
    return phases


def test_dem_progress_has_phases_with_fixed_totals(server, client: LineClient) -> None:
    client.send("dem-full-tof -range -60,60,-50,-20 -name p")
    lines = client.until_final(timeout=300)
    assert lines[-1].status == "OK", lines[-1]
    phases = _check_progress(lines)
    assert [p for p, _ in phases] == ["pointing", "acquire", "process", "write"]
    views = int(lines[-1].fields["views"])
    assert phases[("acquire", "")] == [(i, views) for i in range(views + 1)]
    messages = [r.fields["message"] for r in lines if r.fields.get("phase") == "acquire"]
    assert all(m.startswith("view ") for m in messages)
    assert server.app.jobs.last.progress_dropped == 0


def test_navigate_progress_per_leg_and_phase(server_factory) -> None:
    srv = server_factory(["server.scene=office", NARROW])
    c = srv.client()
    c.send("navigate -goal 1.5,-1.2 -auto -loop scan -scan-plan circle -name prog")
    lines = c.until_final(timeout=300)
    assert lines[-1].status == "OK", lines[-1]
    phases = _check_progress(lines)
    legs = int(lines[-1].fields["legs"])
    assert {leg for _, leg in phases} == {str(k) for k in range(1, legs + 1)}
    assert [p for p, leg in phases if leg == "1"] == ["pointing", "acquire", "process", "write", "plan", "drive"]
    for r in lines:  # "leg" is a navigate leg, never a waypoint segment
        if r.status == "PROGRESS":
            assert " leg" not in r.fields["message"] and "legs" not in r.fields["message"]
    assert srv.app.jobs.last.progress_dropped == 0


def test_rvs_client_draws_a_progress_bar(server, capsys) -> None:
    from rvs_server.client.console import main

    assert main(["--port", str(server.port), "--progress", "bar", "-c", "dem-full-tof -range -30,30,-50,-30"]) == 0
    out = capsys.readouterr().out
    assert "\r" in out and "acquire" in out and "[#" in out and "EGP-RVS-DEM-FULL-TOF OK" in out
    assert "PROGRESS" not in out


# ------------------------------------------------------------------ 5. refusals before the ACK, help


def test_ptu_limits_are_e_arg_before_any_ack(client: LineClient) -> None:
    for request in ("move-ptu -pan 200", "move-ptu -tilt -80", "orient -pan 170", "ground-align -tilt 60"):
        client.send(request)
        r = client.reply()
        assert r.status == "ERROR" and r.fields["code"] == "E_ARG", (request, r)
    assert "limits" in client.request("move-ptu -pan 200").fields["message"]
    r = client.request("dem-update-tof")
    assert r.status == "ERROR" and r.fields["code"] == "E_DATA"  # no DEM yet, and no ACK before it
    client.send("recover -set nosuch")
    assert client.reply().fields["code"] == "E_DATA"


def test_help_shows_values_as_typed_on_the_wire(client: LineClient) -> None:
    for cmd in ("dem-full-tof", "navigate", "grab-tof", "move-ptu", "pose", "hazard-start", "orient"):
        r = client.request(f"help {cmd}")
        for key, text in r.fields.items():
            if key.startswith("opt_"):
                assert "True" not in text and "False" not in text, (cmd, key, text)
                assert "default :" not in text and 'default ""' not in text and "default nan" not in text
    r = client.request("help dem-full-tof")
    assert "default true" in r.fields["opt_mesh"] and "default -150,150,-50,-15" in r.fields["opt_range"]
    assert "default" not in r.fields["opt_name"].split(":")[0]  # empty: the help says what it means


# ------------------------------------------------------------------ 6. modes


def test_sleep_is_refused_in_break_and_break_during_a_job_announces_break_only(server, client) -> None:
    watcher = server.client()
    job = client.start_job("sleep -seconds 30")
    assert server.client().request("break").status == "OK"
    assert client.until_final(job=job)[-1].fields["code"] == "E_INTERRUPTED"
    modes = [r.fields["mode"] for r in watcher.lines_before_status() if r.fields.get("kind") == "mode"]
    assert modes == ["sleep", "break"]
    r = client.request("sleep -seconds 0")
    assert r.status == "ERROR" and r.fields["code"] == "E_STATE"
    assert client.request("continue").fields["mode"] == "ready"
    assert client.request("sleep -seconds 0").status == "OK"



# ------------------------------------------------------------------ 11. the README


def test_the_readme_command_table_lists_every_command() -> None:
    import re

    from rvs_server.table import COMMANDS

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    table = readme[readme.index("| commands | what |"):]
    table = table[: table.index("\n\n")]
    listed = {word for cell in re.findall(r"^\| `([^`]+)`", table, re.M) for word in cell.split()}
    assert set(COMMANDS) <= listed, f"missing from the README: {sorted(set(COMMANDS) - listed)}"
