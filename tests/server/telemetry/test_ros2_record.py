"""Recordings of the ``ros2`` profile (record -start -profile ros2, record.profile with
server.record): the same channels as ROS 2 messages, CDR-encoded, each schema the type's full
definition, as rosbag2 writes them; read back with mcap-ros2-support's decoder (what
``ros2 bag`` relies on: the profile, the encodings, the type names and the definitions), the
values checked against the server's DEM, pose and frames."""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from support.marks import long_test
from support.mcap import transform_matrix
from support.server import wait_for

from prox_workflows.grid import read_geotiff

DEM = "dem-full-tof -range -30,30,-40,-20 -overlap 0.1 -name r2"  # two views


def read_ros2(path: Path) -> tuple[Any, dict[str, tuple[str, str, str, bytes]], dict[str, list[tuple[int, Any]]]]:
    """The file's header; per topic (schema name, schema encoding, message encoding, schema
    text); per topic its (log time, decoded message) in time order."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        channels: dict[str, tuple[str, str, str, bytes]] = {}
        messages: dict[str, list[tuple[int, Any]]] = defaultdict(list)
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            channels[channel.topic] = (schema.name, schema.encoding, channel.message_encoding, schema.data)
            messages[channel.topic].append((message.log_time, decoded))
    return header, channels, messages


def grid_layer(msg: Any, index: int = 0) -> np.ndarray:
    """A GridMap's layer as our north-up raster (grid_map: column-major, cell 0 at +x +y)."""
    layout = msg.data[index].layout
    assert [d.label for d in layout.dim] == ["column_index", "row_index"]
    rows_y, cols_x = layout.dim[0].size, layout.dim[1].size
    return np.asarray(msg.data[index].data, np.float32).reshape(rows_y, cols_x)[:, ::-1]


def test_a_dem_recorded_as_ros2_reads_back_as_ros2_messages(server: Any) -> None:
    c = server.client()
    assert c.request("record -start -name r2 -profile ros2").status == "OK"
    dem = c.request(DEM, timeout=120)
    assert dem.status == "OK", dem
    views = int(dem.fields["views"])
    move = c.request("check-move -dx 0.5")
    assert move.status == "OK"
    st = c.request("status").fields
    stop = c.request("record -stop")
    assert stop.status == "OK" and stop.fields["dropped"] == "0", stop

    assert stop.fields["file"] == "recordings/r2"  # a rosbag2 directory
    header, channels, messages = read_ros2(server.data / "recordings" / "r2" / "r2_0.mcap")
    assert header.profile == "ros2"
    assert sum(len(v) for v in messages.values()) == int(stop.fields["messages"])
    assert {(enc, msg_enc) for _, enc, msg_enc, _ in channels.values()} == {("ros2msg", "cdr")}
    types = {topic: ch[0] for topic, ch in channels.items()}
    assert types["/tf"] == "tf2_msgs/msg/TFMessage" and types["/rover/pose"] == "geometry_msgs/msg/PoseStamped"
    assert types["/tof/points"] == "sensor_msgs/msg/PointCloud2"
    assert types["/tof/depth"] == types["/raw/tof/xyz"] == "sensor_msgs/msg/Image"
    assert types["/map/dem"] == types["/map/hazard"] == "grid_map_msgs/msg/GridMap"
    assert types["/rvs/log"] == "rcl_interfaces/msg/Log"
    assert types["/rvs/wire"] == types["/rvs/job"] == types["/raw/calls"] == types["/nav/check_move"] == \
        "std_msgs/msg/String"
    # each schema carries its dependencies' definitions, as rosbag2 writes them
    grid_schema = channels["/map/dem"][3].decode()
    assert grid_schema.startswith("std_msgs/Header header\n")
    for dep in ("std_msgs/Header", "builtin_interfaces/Time", "grid_map_msgs/GridMapInfo", "geometry_msgs/Pose",
                "std_msgs/Float32MultiArray", "std_msgs/MultiArrayDimension"):
        assert f"\n{'=' * 80}\nMSG: {dep}\n" in grid_schema, dep
    assert "\nMSG: sensor_msgs/PointField\n" in channels["/tof/points"][3].decode()

    counts = Counter({topic: len(v) for topic, v in messages.items()})
    assert counts["/raw/tof/xyz"] == counts["/tof/points"] == counts["/tof/depth"] == views
    layers = {t for t in counts if t.startswith("/map/")}
    assert {"/map/dem", "/map/hazard", "/map/traversability", "/map/slope"} <= layers
    assert all(counts[t] == 1 for t in layers) and counts["/nav/check_move"] == 1

    # the DEM: cell, size, centre and every value as the GeoTIFF holds them
    dem_tif, g = read_geotiff(server.data / "dem" / "r2_dem.tif")
    (_, grid), = messages["/map/dem"]
    assert grid.header.frame_id == "world" and grid.layers == ["dem"] and grid.basic_layers == []
    assert grid.info.resolution == pytest.approx(g.cell)
    assert (grid.info.length_x, grid.info.length_y) == pytest.approx((g.width * g.cell, g.height * g.cell))
    centre = grid.info.pose.position
    assert (centre.x, centre.y) == pytest.approx((g.xmin + g.width * g.cell / 2, g.ymin + g.height * g.cell / 2))
    np.testing.assert_array_equal(grid_layer(grid), dem_tif.astype(np.float32))

    # each cloud: the defined points of its raw frame, x y z intensity as float32
    for (_, cloud), (_, raw) in zip(messages["/tof/points"], messages["/raw/tof/xyz"], strict=True):
        assert cloud.header.frame_id == raw.header.frame_id == "tof" and raw.encoding == "32FC3"
        xyz = np.frombuffer(raw.data, np.float32).reshape(raw.height, raw.width, 3)
        assert cloud.height == 1 and cloud.width == int((xyz[..., 2] > 0).sum()) > 1000
        assert [(f.name, f.offset, f.datatype, f.count) for f in cloud.fields] == [
            ("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("intensity", 12, 7, 1)]
        assert cloud.point_step == 16 and cloud.row_step == 16 * cloud.width and not cloud.is_bigendian
        points = np.frombuffer(cloud.data, np.float32).reshape(-1, 4)
        np.testing.assert_array_equal(points[:, :3], xyz[xyz[..., 2] > 0])
    (_, depth), *_ = messages["/tof/depth"]
    assert depth.encoding == "32FC1" and depth.step == 4 * depth.width

    # the frame tree: every frame, the rover where status says it is
    _, tf = messages["/tf"][-1]
    assert {t.header.frame_id for t in tf.transforms} >= {"world", "rover", "mast", "ptu_pan", "ptu_tilt"}
    assert {t.child_frame_id for t in tf.transforms} >= {"rover", "mast", "ptu_pan", "ptu_tilt", "tof",
                                                          "stereo_left", "stereo_right", "rover_truth"}
    rover = transform_matrix(next(t.transform for t in tf.transforms if t.child_frame_id == "rover"))
    x, y, heading = (float(v) for v in st["pose"].split(","))
    assert rover[:2, 3] == pytest.approx((x, y), abs=1e-3)
    assert np.degrees(np.arctan2(rover[1, 0], rover[0, 0])) == pytest.approx(heading, abs=0.01)
    _, pose = messages["/rover/pose"][-1]
    assert pose.header.frame_id == "world" and (pose.pose.position.x, pose.pose.position.y) == \
        pytest.approx((x, y), abs=1e-3)
    # each tree is logged at its stamp, but one sampled as the recording started: that one is
    # logged at the file's start (Recording.log_time), its content keeping its own time
    start = min(t_ns for t_ns, _ in messages["/tf"])
    for t_ns, tf in messages["/tf"]:
        stamp = tf.transforms[0].header.stamp.sec * 10**9 + tf.transforms[0].header.stamp.nanosec
        assert stamp == t_ns or stamp < t_ns == start, (stamp, t_ns, start)

    # the wire: requests and replies as Log lines, their JSON copy and the check-move's answer
    logs = [m for _, m in messages["/rvs/log"]]
    request = next(m for m in logs if m.msg == DEM)
    assert request.name.startswith("conn ") and request.name.endswith(" >") and request.level == 20
    assert any(m.msg.startswith("EGP-RVS-DEM-FULL-TOF OK") and m.name.endswith(" <") for m in logs)
    assert DEM in [json.loads(m.data)["line"] for _, m in messages["/rvs/wire"]]
    assert json.loads(messages["/rvs/job"][-1][1].data)["fraction"] == 1.0
    (_, answer), = messages["/nav/check_move"]
    assert json.loads(answer.data)["verdict"] == move.fields["verdict"]


def test_a_ros2_recording_is_a_rosbag2_directory_that_rosbags_reads_with_latched_maps(server: Any) -> None:
    """rosbags, an independent ROS 2 implementation, opens the bag by its metadata.yaml as
    ros2 bag play does: the topics, their types and counts, the offered QoS (the maps latched).
    The metadata names each topic from its first message on, so a killed writer's bag has it."""
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import QosDurability as Durability
    from rosbags.rosbag2 import Reader

    c = server.client()
    assert c.request("record -start -name bag -profile ros2").fields["recording"] == "recordings/bag"
    assert c.request(DEM.replace("-name r2", "-name bagdem"), timeout=120).status == "OK"
    bag = server.data / "recordings" / "bag"

    def topics() -> set[str]:
        meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        return {t["topic_metadata"]["name"] for t in meta["topics_with_message_count"]}

    # while recording (what a killed writer leaves): the metadata already names every topic written
    assert wait_for(lambda: {"/map/dem", "/tf", "/raw/tof/xyz"} <= topics())
    stop = c.request("record -stop")
    assert stop.status == "OK" and stop.fields["file"] == "recordings/bag", stop
    assert sorted(p.name for p in bag.iterdir()) == ["bag_0.mcap", "metadata.yaml"]
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 8 and meta["storage_identifier"] == "mcap" and meta["relative_file_paths"] == ["bag_0.mcap"]
    _, _, messages = read_ros2(bag / "bag_0.mcap")
    with Reader(bag) as reader:
        assert reader.message_count == sum(len(v) for v in messages.values()) == int(stop.fields["messages"])
        conns = {c.topic: c for c in reader.connections}
        assert conns["/map/dem"].msgtype == "grid_map_msgs/msg/GridMap"
        assert conns["/tf"].msgtype == "tf2_msgs/msg/TFMessage"
        assert {t: conns[t].msgcount for t in conns} == {t: len(v) for t, v in messages.items()}
        (dem_qos,) = conns["/map/dem"].ext.offered_qos_profiles
        (tf_qos,) = conns["/tf"].ext.offered_qos_profiles
        assert dem_qos.durability == Durability.TRANSIENT_LOCAL and tf_qos.durability == Durability.VOLATILE
    with AnyReader([bag]) as reader:  # the messages decode with the bag's own definitions
        dem = [reader.deserialize(raw, conn.msgtype) for conn, _, raw in reader.messages()
               if conn.topic == "/map/dem"]
        assert len(dem) == 1 and dem[0].layers == ["dem"]


def test_the_profile_is_checked_and_server_record_takes_it(server_factory: Any) -> None:
    srv = server_factory(["server.record=true", "record.profile=ros2"])
    c = srv.client()
    bad = c.request("record -start -profile ros1")
    assert bad.fields["code"] == "E_ARG" and "foxglove" in bad.fields["message"] and "ros2" in bad.fields["message"]
    alone = c.request("record -profile ros2")
    assert alone.fields["code"] == "E_ARG" and "-profile goes with -start" in alone.fields["message"], alone
    assert c.request("grab-tof -output k -type amplitude").status == "OK"
    st = c.request("status").fields
    srv.stop()
    (path,) = (srv.data / "recordings").glob("rvs_*/rvs_*_0.mcap")
    header, channels, messages = read_ros2(path)
    assert header.profile == "ros2" and st["recording"] == f"recordings/{path.parent.name}"
    assert path.name == f"{path.parent.name}_0.mcap" and (path.parent / "metadata.yaml").is_file()
    assert channels["/tof/amplitude"][0] == "sensor_msgs/msg/Image" and len(messages["/tof/amplitude"]) == 1
    (_, image), = messages["/tof/amplitude"]
    assert (image.encoding, image.height, image.width) == ("32FC1", 144, 176)  # the SR4000's


@long_test
def test_a_navigate_recorded_as_ros2_has_its_plan_and_track_as_paths(server_factory: Any) -> None:
    srv = server_factory(["server.scene=office", "navigate.range=-90,30,-50,-10"])
    c = srv.client()
    assert c.request("record -start -name nav -profile ros2").status == "OK"
    final = c.request("navigate -goal 1.5,-1.2 -auto -loop scan -scan-plan circle -name nav", timeout=300)
    assert final.status == "OK", final
    st = c.request("status").fields
    assert c.request("record -stop").fields["dropped"] == "0"
    _, channels, messages = read_ros2(srv.data / "recordings" / "nav" / "nav_0.mcap")
    assert channels["/nav/plan"][0] == channels["/nav/track"][0] == "nav_msgs/msg/Path"
    _, plan = messages["/nav/plan"][-1]
    assert plan.header.frame_id == "world" and len(plan.poses) >= 2
    last = plan.poses[-1].pose.position
    assert (last.x, last.y) == pytest.approx((1.5, -1.2), abs=0.3)
    _, track = messages["/nav/track"][-1]  # the last, sent at the stop
    end = track.poses[-1].pose.position
    truth = [float(v) for v in st["truth"].split(",")]
    assert (end.x, end.y) == pytest.approx(truth[:2], abs=0.05)


def test_the_grid_maps_own_encoder_writes_the_generic_encoders_bytes() -> None:
    """GridMap is encoded by hand (its float32 cells as one block); the bytes must be those of the
    definition-driven encoder, NaN cells, both layouts' dimensions and the trailing indices
    included."""
    from prox_workflows.grid import GridGeometry
    from rvs_server.telemetry.ros2_messages import grid, grid_map_cdr
    from rvs_server.telemetry.ros2_msgs import encoder

    rng = np.random.default_rng(3)
    layers = {"dem": rng.normal(size=(5, 7)).astype(np.float32), "upper": rng.normal(size=(5, 7)).astype(np.float32)}
    layers["dem"][1, 2] = np.nan
    msg = grid(1_234_567_890_123, GridGeometry(0.05, -1.0, 2.0, 7, 5, None), layers)
    as_lists = dict(msg, data=[dict(d, data=d["data"].tolist()) for d in msg["data"]])
    assert grid_map_cdr(msg) == encoder("grid_map_msgs/GridMap")(as_lists)
