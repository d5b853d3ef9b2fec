"""MCAP recordings: record -start/-stop and server.record write the live topics, the raw frames
and the wire lines; the file reads back with the mcap reader, also after a SIGKILL."""

from __future__ import annotations

import json
import signal
import time
from collections import Counter
from pathlib import Path
from typing import Any

from conftest import LineClient, long_test
from mcap.reader import make_reader

from rvs_server.client.session import ServerProcess
from rvs_server.telemetry.recording import FLUSH_S, read_messages

MAGIC = b"\x89MCAP0\r\n"
DEM = "dem-full-tof -range -30,30,-40,-20 -overlap 0.1 -name rec"  # two views


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
    assert c.request("status").fields["recording"] == "recordings/run1.mcap"
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
def test_a_recording_survives_sigkill(tmp_path: Path) -> None:
    """server.record from the start; the process is killed mid-run: the file reads back up to
    the last finished chunk, which is at most FLUSH_S old."""
    srv = ServerProcess(tmp_path / "data", ["--set", "drivers.ptu.time_scale=0", "--set", "sim.time_scale=0",
                                            "--set", "server.warm_up=false", "--set", "server.record=true"])
    srv.start()
    try:
        with LineClient(srv.port) as c:
            for i in range(3):
                assert c.request(f"grab-tof -output k{i} -type amplitude").status == "OK"
            c.send("@late sleep -seconds 30")
            assert "ACK" in [r.status for r in c.lines_before_status()]  # the sleep runs
            time.sleep(2.5 * FLUSH_S)  # the grabs' chunk is finished meanwhile
            assert srv.proc is not None
            srv.proc.send_signal(signal.SIGKILL)
            srv.proc.wait(10)
    finally:
        srv.stop()
    files = list((tmp_path / "data" / "recordings").glob("rvs_*.mcap"))
    assert len(files) == 1
    data = files[0].read_bytes()
    assert data.startswith(MAGIC) and not data.endswith(MAGIC)  # killed: no summary, no footer
    counts = Counter(channel.topic for _, channel, _ in read_messages(files[0]))
    assert counts["/raw/tof/image"] == 3 and counts["/tof/amplitude"] == 3
    lines = [json.loads(m.data)["line"] for _, ch, m in read_messages(files[0]) if ch.topic == "/rvs/wire"]
    assert "@late sleep -seconds 30" in lines
