"""A recording's time range is its own: what is latched (maps, check-move, track) and sent again
to a new recording is logged at the recording's start, its content keeping the time it was made;
whether the hub sends it (no telemetry process yet) or the telemetry process that holds it."""

from __future__ import annotations

import time
from typing import Any

from support.mcap import decoded

DEM = "dem-full-tof -range -30,30,-40,-20 -overlap 0.1 -name rs"  # two views


def test_what_a_new_recording_is_sent_again_is_stamped_at_its_start(server: Any) -> None:
    c = server.client()
    assert c.request(DEM, timeout=120).status == "OK"
    assert c.request("check-move -dx 0.5").status == "OK"
    made = time.time_ns()  # the maps and the check-move are older than this
    for name in ("first", "second"):  # the hub sends what is latched; then the process that kept it
        started = time.time_ns()
        assert c.request(f"record -start -name {name}").status == "OK"
        assert c.request("record -stop").status == "OK"
        messages = decoded(server.data / "recordings" / f"{name}.mcap")
        topics = {topic for topic, _, _ in messages}
        assert {"/map/dem", "/map/hazard", "/nav/check_move", "/nav/track"} <= topics, (name, topics)
        early = [(topic, t) for topic, t, _ in messages if t < started]
        assert not early, (name, early[:5])
        dem = next(msg for topic, _, msg in messages if topic == "/map/dem")
        assert dem.timestamp.seconds * 10**9 + dem.timestamp.nanos < made  # the map's own time
        check = next(msg for topic, _, msg in messages if topic == "/nav/check_move").entities[0]
        assert check.timestamp.seconds * 10**9 + check.timestamp.nanos < made


def test_a_ros2_bags_time_range_is_its_recordings(server: Any) -> None:
    """rosbag2 tools take a bag's time range from its metadata.yaml (``ros2 bag info``, rosbags'
    Reader): it starts at ``record -start`` too, not at the time of the oldest latched map."""
    from rosbags.rosbag2 import Reader

    c = server.client()
    assert c.request(DEM, timeout=120).status == "OK"
    assert c.request("check-move -dx 0.5").status == "OK"
    for name in ("first2", "second2"):
        started = time.time_ns()
        assert c.request(f"record -start -name {name} -profile ros2").status == "OK"
        assert c.request("record -stop").status == "OK"
        stopped = time.time_ns()
        with Reader(server.data / "recordings" / name) as bag:
            assert {"/map/dem", "/nav/check_move", "/nav/track"} <= {conn.topic for conn in bag.connections}
            first = min(t for _, t, _ in bag.messages())
            assert started <= bag.start_time == first, (name, started, bag.start_time, first)
            assert bag.end_time <= stopped, (name, bag.end_time, stopped)
