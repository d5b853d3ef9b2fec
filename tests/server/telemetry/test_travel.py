"""The driven track and the goal are the server's: with no console page open, two navigates
leave the whole path and the last goal in /api/state, the same path as Foxglove's /nav/track;
a broken navigate takes its goal off the map. And the pose channels of a recording made while
the rover drives move forward in time, never faster than the rover can drive."""

from __future__ import annotations

import json
import math
import socket
import urllib.request
from typing import Any

import pytest
from support.marks import long_test
from support.mcap import decoded, transform_matrix
from support.server import wait_for

TIME_SCALE = 20.0  # simulated seconds per wall second: the rover drives at SPEED * TIME_SCALE m/s of wall time
SPEED = 0.1  # m/s, the scene's drive model (config/scenes)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def api_state(port: int) -> dict[str, Any]:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/state", timeout=30) as resp:
        return json.loads(resp.read())


def pose_xy(topic: str, message: Any) -> tuple[float, float]:
    if topic == "/tf":
        T = transform_matrix(next(tf for tf in message.transforms if tf.child_frame_id == "rover_truth"))
        return float(T[0, 3]), float(T[1, 3])
    return message.pose.position.x, message.pose.position.y


@long_test
def test_track_and_goal_are_the_servers_and_the_recorded_poses_move_as_the_rover_can(server_factory: Any) -> None:
    web_port = free_port()
    srv = server_factory([f"server.web_port={web_port}", f"sim.time_scale={TIME_SCALE:g}"])
    c = srv.client()
    assert c.request("record -start -name drive").status == "OK"
    for goal in ("0.8,0.4", "0.3,-0.1"):
        final = c.request(f"navigate -goal {goal} -auto true", timeout=600)
        assert final.status == "OK", final
    st = c.request("status").fields
    assert c.request("record -stop").status == "OK"
    assert not srv.app.console.pages  # nobody watched

    state = api_state(web_port)
    assert state["goal"]["x"] == pytest.approx(0.3) and state["goal"]["y"] == pytest.approx(-0.1), state["goal"]
    track = state["track"]
    truth = [float(v) for v in st["truth"].split(",")]
    # the whole path: from the start, by the first goal, to where the rover stands
    assert len(track) > 20, track
    assert math.dist(track[0], (0.0, 0.0)) < 0.05, track[:3]
    assert min(math.dist(p, (0.8, 0.4)) for p in track) < 0.35, track
    assert math.dist(track[-1], truth[:2]) < 0.05, (track[-1], truth)

    messages = decoded(srv.data / "recordings" / "drive.mcap")
    # Foxglove's track is the same path
    recorded = [msg for topic, _, msg in messages if topic == "/nav/track"][-1].entities[0].lines[0].points
    assert [(round(p.x, 3), round(p.y, 3)) for p in recorded] == [tuple(p) for p in track]

    # each pose channel, in the order written and in time: forward only, at the rover's speed at most
    for topic in ("/tf", "/rover/pose", "/rover/truth"):
        stamped = [(t, pose_xy(topic, msg)) for name, t, msg in messages if name == topic]
        assert len(stamped) > 20, topic
        times = [t for t, _ in stamped]
        assert all(b > a for a, b in zip(times, times[1:], strict=False)), f"{topic} steps back in time"
        for (t0, p0), (t1, p1) in zip(stamped, stamped[1:], strict=False):
            allowed = SPEED * TIME_SCALE * (t1 - t0) / 1e9 * 1.5 + 0.03
            assert math.dist(p0, p1) <= allowed, (topic, t0, p0, t1, p1)

    # a navigate that ends in a break leaves no goal on the map
    job = c.start_job("navigate -goal -1.0,0.5 -auto true")
    assert wait_for(lambda: (goal := srv.app.travel.goal) is not None and goal.job == int(job), 60.0)
    assert api_state(web_port)["goal"]["x"] == pytest.approx(-1.0)
    assert c.request("break").status == "OK"
    assert c.until_final(job=job)[-1].fields["code"] == "E_INTERRUPTED"
    assert api_state(web_port)["goal"] is None
