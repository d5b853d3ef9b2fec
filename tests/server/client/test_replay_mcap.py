"""Recorded runs replayed through the real code path: a simulated run recorded to MCAP runs
again on the replay backends (no simulated world, no hardware), over real TCP, with the same
replies and the same DEM cell for cell; a request the recording cannot answer is E_DEVICE and
the server goes on serving."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.server import LineClient, ServerThread

from prox_workflows.grid import read_geotiff
from rvs_server.client.recording_replay import (
    compare,
    recorded_exchanges,
    replay,
    replay_sets,
    replayed_kinds,
)
from rvs_server.client.replay import main as rvs_replay

DEM = "dem-full-tof -range -30,30,-40,-20 -overlap 0.1 -name rec"  # two views
RUN = [DEM, "check-move -dx 0.5", "move-ptu -pan 12 -tilt -25", "grab-tof -output amp -type amplitude",
       "pose -x 0.2 -y 0.1 -heading 5", "status"]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A simulated run recorded: a two-view DEM, a check-move, a PTU move and a 2-D ToF grab."""
    data = tmp_path_factory.mktemp("recorded")
    srv = ServerThread(data).start()
    try:
        c = srv.client()
        assert c.request("record -start -name run").status == "OK"
        replies = [c.request(line, timeout=120) for line in RUN]
        assert all(r.status == "OK" for r in replies), replies
        assert c.request("record -stop").status == "OK"
        c.close()
    finally:
        srv.stop()
    return {"path": data / "recordings" / "run.mcap", "data": data, "replies": replies}


def test_a_recorded_dem_replays_with_the_same_replies_and_the_same_dem(recording: dict[str, Any],
                                                                          tmp_path: Path) -> None:
    out = replay(recording["path"], tmp_path / "replay", products=True)
    assert out.problems == [] and out.sent == len(RUN), out
    assert out.maps >= 9, out  # every layer of the DEM compared, not an empty comparison
    for layer in ("dem", "hazard", "ortho", "count"):
        want, g1 = read_geotiff(recording["data"] / "dem" / f"rec_{layer}.tif")
        got, g2 = read_geotiff(tmp_path / "replay" / "dem" / f"rec_{layer}.tif")
        assert g1 == g2 and np.array_equal(want, got, equal_nan=True), layer
    assert np.isfinite(want).any()
    # the replay ran on replay backends only, and recorded itself: a replay of the replay matches too
    again = replay(out.recording, tmp_path / "again", products=True)
    assert again.problems == [] and again.sent == len(RUN), again


def test_rvs_replay_mcap_prints_a_summary_and_fails_on_a_mismatch(recording: dict[str, Any], tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    assert rvs_replay(["--mcap", str(recording["path"]), "--data", str(tmp_path / "r")]) == 0
    assert f"{len(RUN)} requests replayed" in capsys.readouterr().out
    # the comparison is not blind: a reply that differs in a compared field is a mismatch
    recorded = recorded_exchanges(recording["path"])
    altered = recorded_exchanges(recording["path"])
    dem = next(ex for ex in altered if ex.request == DEM)
    final = dem.lines[-1][1]
    final.fields["cells"] = str(int(final.fields["cells"]) + 1)
    assert len(compare(recorded, altered)) == 1
    assert compare(recorded, recorded_exchanges(recording["path"])) == []


def _replay_server(server_factory: Any, path: Path) -> tuple[Any, LineClient]:
    sets = [s for s in replay_sets(path, Path("unused"), "fast") if not s.startswith(("server.data", "server.port"))]
    srv = server_factory(sets)
    assert {srv.app.devices.devices[k].backend for k in replayed_kinds()} == {"replay"}
    return srv, srv.client()


def test_what_the_recording_cannot_answer_is_e_device_and_the_server_serves_on(recording: dict[str, Any],
                                                                                server_factory: Any) -> None:
    _, c = _replay_server(server_factory, recording["path"])
    # the first recorded frame was taken at the DEM's first view, not where the PTU starts
    here = c.request("grab-tof -output a -type amplitude", timeout=60)
    assert here.fields["code"] == "E_DEVICE" and "holds no frame from here" in here.fields["message"], here
    assert c.request("status").status == "OK"
    assert c.request("reset", timeout=60).status == "OK"
    # frames are served where they were taken: the DEM's second view (4 frames: one is enough here)
    assert c.request("move-ptu -pan 8.2 -tilt -30", timeout=60).status == "OK"
    assert c.request("grab-tof -output b -type amplitude", timeout=60).status == "OK"
    # the 2-D grab's pointing; it had one frame, a grab of two has no second
    assert c.request("move-ptu -pan 12 -tilt -25", timeout=60).status == "OK"
    more = c.request("grab-tof -output c -type amplitude -integrate 2", timeout=60)
    assert more.fields["code"] == "E_DEVICE" and "fewer frames" in more.fields["message"], more
    assert c.request("reset", timeout=60).status == "OK"
    past = c.request("grab-tof -output c -type amplitude", timeout=60)
    assert past.fields["code"] == "E_DEVICE" and "all were served" in past.fields["message"], past
    assert c.request("status").status == "OK"


def cut_after_first_grab(src: Path, dst: Path) -> None:
    """``src`` as a writer killed just after its first ToF grab leaves it: whole chunks up to
    there, then a torn record, no summary."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f:
        reader = make_reader(f)
        metadata = next(m for m in reader.iter_metadata() if m.name == "rvs")
        messages = list(reader.iter_messages(log_time_order=False))
    with open(dst, "wb") as out:
        writer = Writer(out, chunk_size=1)
        writer.start()
        writer.add_metadata("rvs", dict(metadata.metadata))
        ids: dict[str, int] = {}
        grabs = 0
        for schema, channel, message in messages:
            if channel.topic == "/raw/calls" and b'"tof"' in message.data:
                grabs += 1
                if grabs == 2:
                    break
            if channel.topic not in ids:
                sid = writer.register_schema(schema.name, schema.encoding, schema.data) if schema else 0
                ids[channel.topic] = writer.register_channel(channel.topic, channel.message_encoding, sid)
            writer.add_message(ids[channel.topic], message.log_time, message.data, message.publish_time)
        out.write(b"\x06\xff\xff")  # the start of the next record, then nothing


def test_a_truncated_recording_replays_up_to_its_cut(recording: dict[str, Any], server_factory: Any,
                                                     tmp_path: Path) -> None:
    cut = tmp_path / "cut.mcap"
    cut_after_first_grab(recording["path"], cut)
    _, c = _replay_server(server_factory, cut)
    dem = c.request(DEM, timeout=120)  # its first view is in the file, its second is not
    assert dem.fields["code"] == "E_DEVICE" and "torn at its end" in dem.fields["message"], dem
    assert "1 tof frame call(s) and all were served" in dem.fields["message"], dem
    assert c.request("status").status == "OK"


def test_a_replay_without_a_recording_says_what_to_set(server_factory: Any) -> None:
    srv = server_factory(["drivers.tof.backend=replay"])
    c = srv.client()
    assert c.request("grab-tof -output x", timeout=60).fields["code"] == "E_STATE"  # the camera did not open
    reset = c.request("reset", timeout=60)
    assert reset.fields["code"] == "E_DEVICE" and "drivers.tof.replay_file" in reset.fields["message"], reset


def test_a_replayed_drive_is_the_recorded_poses_from_the_first_move_to_where_the_rover_stood() -> None:
    from drivers.rover.replay import drive_after

    s = 1_000_000_000
    still = [(i * s // 10, 0.0, 0.0, 0.0) for i in range(5)]  # standing, sampled at 10 Hz
    moving = [(5 * s // 10 + i * s // 10, 0.05 * (i + 1), 0.0, 0.0) for i in range(10)]
    stood = [(15 * s // 10 + i * s // 10, 0.5, 0.0, 0.0) for i in range(15)]  # 1.5 s still
    later = [(31 * s // 10, 0.6, 0.0, 0.0)]  # a second drive
    poses = still + moving + stood + later
    drive = drive_after(poses, after_ns=2 * s // 10)
    assert np.allclose([p[1] for p in drive], [0.05 * (i + 1) for i in range(10)])
    assert drive_after(poses, after_ns=drive[-1][0]) == later
    assert drive_after(poses, after_ns=later[0][0]) == []
