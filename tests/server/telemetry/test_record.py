"""MCAP recordings: record -start/-stop and server.record write the live topics, the raw frames
and the wire lines from a telemetry process of the server's own; the file reads back with the
mcap reader, whole after a SIGKILL of the server, up to its last second after one of the
telemetry process. The telemetry process's queue drops what only the live view wants first."""

from __future__ import annotations

import json
import os
import signal
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from support.marks import long_test
from support.server import LineClient, wait_for

from rvs_server.client.session import ServerProcess
from rvs_server.telemetry import link as telemetry_link
from rvs_server.telemetry.link import LIVE_BYTES, QUEUE_BYTES, Link
from rvs_server.telemetry.recording import FLUSH_S, read_messages

MAGIC = b"\x89MCAP0\r\n"
DEM = "dem-full-tof -range -30,30,-40,-20 -overlap 0.1 -name rec"  # two views


def telemetry_pid(parent: int) -> int:
    """The telemetry process the server ``parent`` started (it may be starting)."""
    found: list[int] = []

    def look() -> bool:
        for task in Path(f"/proc/{parent}/task").iterdir():
            for pid in (task / "children").read_text().split():
                if "rvs_server.telemetry.worker" in Path(f"/proc/{pid}/cmdline").read_text():
                    found.append(int(pid))
        return bool(found)

    assert wait_for(look, 30.0), f"{parent} has no telemetry process"
    return found[0]


def holds_open(pid: int, path: Path) -> bool:
    fds = Path(f"/proc/{pid}/fd")
    return any(os.readlink(fd) == str(path) for fd in fds.iterdir() if fd.is_symlink())


def summary(path: Path) -> tuple[Counter[str], dict[str, str], list[Any]]:
    """Messages per topic and each topic's schema name, from the file's summary; and the
    messages' (topic, log time, data) in file order."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        s = reader.get_summary()
        assert s is not None and s.statistics is not None
        counts = Counter({s.channels[cid].topic: n for cid, n in s.statistics.channel_message_counts.items()})
        schemas = {ch.topic: s.schemas[ch.schema_id].name for ch in s.channels.values()}
        messages = [(ch.topic, msg.log_time, msg.data) for _, ch, msg in reader.iter_messages(log_time_order=False)]
    return counts, schemas, messages


def test_record_a_dem_and_read_it_back(server: Any) -> None:
    c = server.client()
    assert c.request("record -stop").fields["code"] == "E_STATE"
    ok = c.request("record -start -name run1")
    assert ok.status == "OK" and ok.fields["recording"] == "recordings/run1.mcap", ok
    assert c.request("record -start").fields["code"] == "E_STATE"
    st = c.request("status").fields
    assert st["recording"] == "recordings/run1.mcap" and st["recording_dropped"] == "0", st
    # the MCAP writer is the telemetry process's, not the server's
    path = server.data / "recordings" / "run1.mcap"
    assert holds_open(telemetry_pid(os.getpid()), path) and not holds_open(os.getpid(), path)
    dem = c.request(DEM, timeout=120)
    assert dem.status == "OK", dem
    views = int(dem.fields["views"])
    assert c.request("check-move -dx 0.5").status == "OK"
    stop = c.request("record -stop")
    assert stop.status == "OK" and stop.fields["file"] == "recordings/run1.mcap" and stop.fields["dropped"] == "0", stop
    assert c.request("record").fields["recording"] == "none"

    counts, schemas, messages = summary(server.data / "recordings" / "run1.mcap")
    assert sum(counts.values()) == int(stop.fields["messages"])
    # each view's full-resolution frame, raw and as the live cloud and images
    assert counts["/raw/tof/xyz"] == counts["/raw/tof/amplitude"] == counts["/tof/points"] == views
    assert schemas["/raw/tof/xyz"] == "foxglove.RawImage" and schemas["/tof/points"] == "foxglove.PointCloud"
    # one Grid per layer the DEM job wrote
    layers = {t for t in counts if t.startswith("/map/") and counts[t]}
    assert {"/map/dem", "/map/hazard", "/map/traversability", "/map/ortho", "/map/slope"} <= layers
    assert all(counts[t] == 1 and schemas[t] == "foxglove.Grid" for t in layers)
    assert counts["/nav/check_move"] == 1 and schemas["/nav/check_move"] == "foxglove.SceneUpdate"
    assert counts["/tf"] > views and schemas["/tf"] == "foxglove.FrameTransforms"
    assert schemas["/rvs/log"] == "foxglove.Log" and schemas["/rvs/job"] == "rvs.JobProgress"
    # the wire: the requests and their final lines, in order, with their times
    wire = [(t, json.loads(data)) for topic, t, data in messages if topic == "/rvs/wire"]
    lines = [w["line"] for _, w in wire]
    assert lines.index(DEM) < lines.index(next(x for x in lines if x.startswith("EGP-RVS-DEM-FULL-TOF OK")))
    assert "check-move -dx 0.5" in lines and any(x.startswith("EGP-RVS-CHECK-MOVE OK") for x in lines)
    assert [t for t, _ in wire] == sorted(t for t, _ in wire)
    assert {w["dir"] for _, w in wire} >= {"request", "reply", "event"}
    progress = [json.loads(data) for topic, _, data in messages if topic == "/rvs/job"]
    assert progress[-1]["status"] == "OK" and progress[-1]["fraction"] == 1.0

    # a recording started later stands alone: the current maps and check-move, once each
    assert c.request("record -start -name run2").status == "OK"
    assert c.request("record -stop").status == "OK"
    later, _, _ = summary(server.data / "recordings" / "run2.mcap")
    assert {t for t in later if t.startswith("/map/") and later[t]} == layers
    assert all(later[t] == 1 for t in layers) and later["/nav/check_move"] == 1, later


def test_record_refuses_what_it_cannot_do(server: Any) -> None:
    c = server.client()
    assert c.request("record -start -stop").fields["code"] == "E_ARG"
    assert c.request("record -name x").fields["code"] == "E_ARG"
    assert c.request("record -start -name ../x").fields["code"] == "E_ARG"
    assert c.request("record -start -name twice").status == "OK"
    assert c.request("record -stop").status == "OK"
    again = c.request("record -start -name twice")
    assert again.fields["code"] == "E_ARG" and "exists" in again.fields["message"], again


@long_test
def test_a_recording_survives_a_sigkill_of_the_server(tmp_path: Path) -> None:
    """server.record from the start; the server is killed mid-run: its telemetry process sees
    its pipe close, finishes the file (summary and all) and exits."""
    srv = ServerProcess(tmp_path / "data", ["--set", "drivers.ptu.time_scale=0", "--set", "sim.time_scale=0",
                                            "--set", "server.warm_up=false", "--set", "server.record=true"])
    srv.start()
    try:
        assert srv.proc is not None
        worker = telemetry_pid(srv.proc.pid)
        with LineClient(srv.port) as c:
            for i in range(3):
                assert c.request(f"grab-tof -output k{i} -type amplitude").status == "OK"
            c.send("@late sleep -seconds 30")
            assert "ACK" in [r.status for r in c.lines_before_status()]  # the sleep runs
            time.sleep(0.5)  # the line reaches the telemetry process
            srv.proc.send_signal(signal.SIGKILL)
            srv.proc.wait(10)
        assert wait_for(lambda: not Path(f"/proc/{worker}").exists(), 20.0), "the telemetry process lingers"
    finally:
        srv.stop()
    files = list((tmp_path / "data" / "recordings").glob("rvs_*.mcap"))
    assert len(files) == 1
    assert files[0].read_bytes().endswith(MAGIC)  # the footer: the file was finished
    counts, _, messages = summary(files[0])
    assert counts["/raw/tof/image"] == 3 and counts["/tof/amplitude"] == 3
    lines = [json.loads(data)["line"] for topic, _, data in messages if topic == "/rvs/wire"]
    assert "@late sleep -seconds 30" in lines


def test_a_killed_telemetry_process_costs_the_last_second(server: Any) -> None:
    """The telemetry process is killed mid-recording: the file reads back up to the last chunk
    it finished (at most FLUSH_S old); the server says so and records again in a new process."""
    c = server.client()
    assert c.request("record -start -name cut").status == "OK"
    for i in range(3):
        assert c.request(f"grab-tof -output k{i} -type amplitude").status == "OK"
    time.sleep(2.5 * FLUSH_S)  # the grabs' chunk is finished meanwhile
    worker = telemetry_pid(os.getpid())
    os.kill(worker, signal.SIGKILL)
    assert wait_for(lambda: "exited" in c.request("status").fields["foxglove_reason"], 10.0)
    stop = c.request("record -stop")
    assert stop.fields["code"] == "E_IO" and "recordings/cut.mcap" in stop.fields["message"], stop
    path = server.data / "recordings" / "cut.mcap"
    assert not path.read_bytes().endswith(MAGIC)  # killed: no summary, no footer
    counts = Counter(channel.topic for _, channel, _ in read_messages(path))
    assert counts["/raw/tof/image"] == 3 and counts["/tof/amplitude"] == 3
    assert c.request("record -start -name again").status == "OK"
    assert telemetry_pid(os.getpid()) != worker
    assert c.request("record -stop").status == "OK"


def test_a_stalled_telemetry_process_drops_live_messages_first(monkeypatch: Any) -> None:
    """No thread waits for a telemetry process that does not read: past LIVE_BYTES queued a
    message only the live view wants is dropped, a recorded one only past QUEUE_BYTES."""
    image = np.zeros(16 * 1024 * 1024, np.uint8)  # one array, queued many times: the bounds count each
    monkeypatch.setattr(telemetry_link, "PIPE_BYTES", 64 * 1024)  # the pipe takes none of it
    link = Link("127.0.0.1", 0, "test")
    os.kill(link.proc.pid, signal.SIGSTOP)
    try:
        for _ in range(10):
            link.log("/tof/depth", 0, np.copy, image)
        live_fit = LIVE_BYTES // (image.nbytes + 256)
        assert (link.live_dropped, link.dropped) == (10 - live_fit, 0)
        link.recording = True
        for _ in range(40):
            link.log("/tof/depth", 0, np.copy, image)
        kept = QUEUE_BYTES // (image.nbytes + 256) - live_fit
        assert (link.live_dropped, link.dropped) == (10 - live_fit, 40 - kept)
    finally:
        os.kill(link.proc.pid, signal.SIGCONT)
    link.close()
    assert link.proc.returncode == 0 and link.exited is not None
