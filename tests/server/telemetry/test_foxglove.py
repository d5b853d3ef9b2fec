"""Foxglove live: a client speaking the foxglove.websocket.v1 protocol (from its spec; the SDK
names the subprotocol foxglove.sdk.v1) connects, lists the channels, subscribes and decodes
the protobuf messages with the schemas the server advertises, as the Foxglove app does; what
it decodes is checked against the server's own map, pose and DEM, and with the body hazard
cameras on, against the pair the device grabbed."""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import os
import socket
import struct
from pathlib import Path
from typing import Any

import aiohttp
import cv2
import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from support.marks import long_only
from support.mcap import transform_matrix
from support.server import wait_for

from prox_workflows.grid import read_geotiff
from rvs_server.bus import tapped_call

SUBPROTOCOL = "foxglove.sdk.v1"
DEM = "dem-full-tof -range -30,30,-40,-20 -overlap 0.1 -name fx"  # two views: a second or two


def listener_pid(port: int) -> int:
    """The process listening on TCP ``port`` (from /proc: the socket's inode, then whose fd it is)."""
    inodes = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for row in Path(table).read_text().splitlines()[1:]:
            cols = row.split()
            if int(cols[1].rsplit(":", 1)[1], 16) == port and cols[3] == "0A":  # 0A: LISTEN
                inodes.add(f"socket:[{cols[9]}]")
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            if any(os.readlink(f"/proc/{pid}/fd/{fd}") in inodes for fd in os.listdir(f"/proc/{pid}/fd")):
                return int(pid)
        except OSError:  # gone meanwhile, or not ours to read
            continue
    raise AssertionError(f"nothing listens on {port}")


def parent_of(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class FoxgloveClient:
    """The client side of foxglove.websocket.v1: serverInfo and advertise arrive first; a
    subscribe names (subscription id, channel id); each message comes as a binary frame: opcode
    1, the subscription id (uint32 LE), the log time (uint64 LE, ns), the payload."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.ws = ws
        self.info: dict[str, Any] = {}
        self.channels: dict[str, dict[str, Any]] = {}  # topic -> advertised channel
        self.subscriptions: dict[int, str] = {}  # subscription id -> topic
        self.classes: dict[str, Any] = {}
        self.trees: dict[int, Any] = {}  # every frame tree received, by its time

    async def hello(self) -> None:
        while not self.info or not self.channels:
            msg = await self.ws.receive(timeout=10)
            assert msg.type == aiohttp.WSMsgType.TEXT, msg
            self._text(json.loads(msg.data))

    def _text(self, obj: dict[str, Any]) -> None:
        if obj["op"] == "serverInfo":
            self.info = obj
        elif obj["op"] == "advertise":
            for ch in obj["channels"]:
                self.channels[ch["topic"]] = ch

    async def advertised(self, *topics: str, timeout: float = 30.0) -> None:
        """Until every one of ``topics`` is advertised (a channel is, once it has said something)."""
        async with asyncio.timeout(timeout):
            while not set(topics) <= set(self.channels):
                msg = await self.ws.receive()
                assert msg.type == aiohttp.WSMsgType.TEXT, msg
                self._text(json.loads(msg.data))

    async def subscribe(self, *topics: str) -> None:
        subs = []
        for topic in topics:
            sub = len(self.subscriptions) + 1
            self.subscriptions[sub] = topic
            subs.append({"id": sub, "channelId": self.channels[topic]["id"]})
        await self.ws.send_str(json.dumps({"op": "subscribe", "subscriptions": subs}))

    def decode(self, topic: str, payload: bytes) -> Any:
        ch = self.channels[topic]
        if ch["encoding"] == "json":
            return json.loads(payload)
        if ch["schemaName"] not in self.classes:
            pool = descriptor_pool.DescriptorPool()
            for f in descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(ch["schema"])).file:
                pool.Add(f)
            self.classes[ch["schemaName"]] = message_factory.GetMessageClass(
                pool.FindMessageTypeByName(ch["schemaName"]))
        return self.classes[ch["schemaName"]].FromString(payload)

    async def next(self, timeout: float = 30.0) -> tuple[str, int, Any]:
        """The next message on a subscribed channel: (topic, log time, decoded message)."""
        while True:
            msg = await self.ws.receive(timeout=timeout)
            if msg.type == aiohttp.WSMsgType.TEXT:
                self._text(json.loads(msg.data))
                continue
            assert msg.type == aiohttp.WSMsgType.BINARY, msg
            op, sub, t = struct.unpack_from("<BIQ", msg.data)
            assert op == 1
            topic = self.subscriptions[sub]
            message = self.decode(topic, msg.data[13:])
            if topic == "/tf":
                self.trees[t] = message
            return topic, t, message

    async def until(self, topic: str, timeout: float = 60.0) -> tuple[int, Any]:
        async with asyncio.timeout(timeout):
            while True:
                got, t, message = await self.next(timeout)
                if got == topic:
                    return t, message


def chain(transforms: Any, child: str) -> np.ndarray:
    """world <- child through the tree's parent links."""
    by_child = {tf.child_frame_id: tf for tf in transforms}
    T = np.eye(4)
    while child != "world":
        tf = by_child[child]
        T = transform_matrix(tf) @ T
        child = tf.parent_frame_id
    return T


def grid_values(grid: Any) -> np.ndarray:
    """A Grid's single field as rows north first, as the server's GeoTIFFs hold them."""
    dtype = {7: np.float32, 1: np.uint8, 6: np.int32}[grid.fields[0].type]
    rows = np.frombuffer(grid.data, dtype).reshape(-1, grid.column_count)
    return np.flipud(rows)


async def connect(port: int, protocols: tuple[str, ...] = (SUBPROTOCOL,)) -> tuple[aiohttp.ClientSession,
                                                                                 FoxgloveClient]:
    session = aiohttp.ClientSession()
    ws = await session.ws_connect(f"ws://127.0.0.1:{port}", protocols=protocols)
    client = FoxgloveClient(ws)
    await client.hello()
    return session, client


def test_foxglove_client_decodes_grid_cloud_and_frames(server_factory: Any) -> None:
    port = free_port()
    # quarry: the rover stands rolled 0.8 deg and pitched -0.3 deg, which its frames are placed with
    srv = server_factory([f"server.foxglove_port={port}", "server.scene=quarry"])
    c = srv.client()
    status = c.request("status").fields
    assert status["foxglove"] == "on" and status["foxglove_url"] == f"ws://127.0.0.1:{port}", status
    assert c.request(DEM, timeout=120).status == "OK"  # a channel is advertised once it has said something

    async def live() -> dict[str, Any]:
        session, fx = await connect(port)
        try:
            # read-only whoever connects: nothing a client could publish, call or set
            assert not set(fx.info["capabilities"]) & {"clientPublish", "services", "parameters"}, fx.info
            await fx.advertised("/tf", "/rover/pose", "/rover/truth", "/tof/points", "/tof/depth", "/tof/amplitude",
                                "/rvs/log", "/rvs/job", "/map/dem")
            assert not [t for t in fx.channels if t.startswith("/raw/") or t == "/rvs/wire"]  # recordings only
            assert fx.channels["/tof/points"]["schemaName"] == "foxglove.PointCloud"
            await fx.subscribe("/tf", "/tof/points", "/rvs/log")
            await fx.until("/tf")  # the subscription is live before the scan starts
            job = asyncio.get_running_loop().run_in_executor(None, c.request, DEM, 120.0)
            t_cloud, cloud = await fx.until("/tof/points")
            reply = await job
            assert reply.status == "OK", reply
            st = c.request("status").fields
            await fx.subscribe(*[t for t in fx.channels if t.startswith("/map/")] or ["/map/dem"])
            # the tree of the cloud's time: the newest at its start (the call's state, stamped before it)
            return {"cloud": cloud, "tree": fx.trees[max(t for t in fx.trees if t <= t_cloud)], "status": st,
                    "dem": (await fx.until("/map/dem"))[1], "latest": (await fx.until("/tf"))[1]}
        finally:
            await fx.ws.close()
            await session.close()

    got = asyncio.run(live())
    cloud, tree, st = got["cloud"], got["tree"], got["status"]

    # the Grid is the server's DEM: size, cell, origin at the south-west corner, every cell
    dem, geometry = read_geotiff(srv.data / "dem" / "fx_dem.tif")
    grid = got["dem"]
    assert grid.frame_id == "world" and grid.column_count == geometry.width
    assert grid.cell_size.x == pytest.approx(geometry.cell) and grid.cell_size.y == pytest.approx(geometry.cell)
    assert (grid.pose.position.x, grid.pose.position.y) == pytest.approx((geometry.xmin, geometry.ymin))
    np.testing.assert_array_equal(grid_values(grid), dem)

    # the frame tree: the rover where status says, true and believed, and every sensor frame
    latest = got["latest"].transforms
    assert {tf.child_frame_id for tf in latest} >= {"rover", "mast", "ptu_pan", "ptu_tilt", "tof", "stereo_left",
                                                     "stereo_right", "rover_truth"}
    rover = transform_matrix(next(tf for tf in latest if tf.child_frame_id == "rover"))
    pose = [float(v) for v in st["pose"].split(",")]
    assert rover[:2, 3] == pytest.approx(pose[:2], abs=1e-3)
    assert np.degrees(np.arctan2(rover[1, 0], rover[0, 0])) == pytest.approx(pose[2], abs=0.01)
    truth = transform_matrix(next(tf for tf in latest if tf.child_frame_id == "rover_truth"))
    assert truth[:2, 3] == pytest.approx([float(v) for v in st["truth"].split(",")][:2], abs=1e-3)
    # both lean as the body rests: the truth's attitude, and the IMU's read the frames were placed
    # with (its error 0.1 deg)
    true = c.request("sim truth").fields
    for T, tolerance in ((truth, 1e-3), (rover, 0.35)):
        R = T[:3, :3]
        assert np.degrees(np.arcsin(R[2, 0])) == pytest.approx(float(true["pitch"]), abs=tolerance)
        assert np.degrees(np.arctan2(R[2, 1], R[2, 2])) == pytest.approx(float(true["roll"]), abs=tolerance)

    # the cloud, put in the world through the tree of its own time, lies on the DEM made from it
    assert cloud.frame_id == "tof" and cloud.point_stride == 16
    assert [f.name for f in cloud.fields] == ["x", "y", "z", "intensity"]
    pts = np.frombuffer(cloud.data, np.float32).reshape(-1, 4)
    assert len(pts) > 5000
    T = chain(tree.transforms, "tof")
    world = pts[:, :3] @ T[:3, :3].T + T[:3, 3]
    row, col = geometry.cell_of(world[:, 0], world[:, 1])
    inside = geometry.inside(row, col)
    ground = dem[row[inside], col[inside]]
    err = np.abs(world[inside, 2] - ground)[np.isfinite(ground)]
    # to the millimetre: the tree leans the rover frame by the attitude the scan placed it with
    assert len(err) > 0.5 * len(pts) and np.median(err) < 0.005, (len(err), np.median(err))


def test_a_client_that_subscribes_late_gets_the_map_and_a_taken_port_costs_only_foxglove(
        server_factory: Any, tmp_path: Path) -> None:
    port = free_port()
    srv = server_factory([f"server.foxglove_port={port}"])
    c = srv.client()
    assert c.request(DEM, timeout=120).status == "OK"
    assert c.request("check-move -dx 0.5").status == "OK"

    async def late() -> tuple[Any, Any]:
        session, fx = await connect(port)
        try:
            await fx.subscribe("/map/traversability", "/nav/check_move")
            first = await fx.until("/map/traversability")
            return first[1], (await fx.until("/nav/check_move"))[1]
        finally:
            await fx.ws.close()
            await session.close()

    # the SDK runs in a process of the server's own, which a stopped server leaves none of
    owner = listener_pid(port)
    assert owner != os.getpid() and parent_of(owner) == os.getpid()
    assert c.request("status").fields["foxglove_dropped"] == "0"
    # nobody listened: the maps stayed in the server, not piped to the process (10 x 1-100 MB)
    link = srv.app.telemetry.link
    assert not any(topic.startswith("/map/") for topic in link.logged), link.logged

    grid, scene = asyncio.run(late())
    assert link.logged["/map/traversability"] == 1 and link.logged["/map/dem"] == 0  # what was asked for
    trav, _ = read_geotiff(srv.data / "dem" / "fx_traversability.tif")
    np.testing.assert_array_equal(grid_values(grid), trav)
    entity = scene.entities[0]
    assert entity.id == "check_move" and entity.texts[0].text.startswith("check-move: ")

    # a second server on the same Foxglove port starts without it and says why
    other = server_factory([f"server.foxglove_port={port}"])
    st = other.client().request("status").fields
    assert st["foxglove"] == "off" and str(port) in st["foxglove_reason"], st
    srv.stop()
    assert wait_for(lambda: not Path(f"/proc/{owner}").exists(), 10.0)


def test_foxglove_client_sees_the_hazcam_frames_and_decodes_their_image_and_points(server_factory: Any) -> None:
    port = free_port()
    srv = server_factory([f"server.foxglove_port={port}", "drivers.hazcam.cameras=front"])
    hazcam = srv.app.devices.get("hazcam")
    image_topic, points_topic = "/hazcam/front/left/compressed", "/hazcam/front/points"
    tapped_call(srv.app.bus, hazcam.grab, "front")  # its channels are advertised once it has grabbed

    async def live() -> tuple[Any, Any, dict[str, Any]]:
        session, fx = await connect(port)
        try:
            await fx.advertised(image_topic, points_topic)
            assert fx.channels[image_topic]["schemaName"] == "foxglove.CompressedImage"
            assert fx.channels[points_topic]["schemaName"] == "foxglove.PointCloud"
            await fx.subscribe("/tf", image_topic, points_topic)
            tree = (await fx.until("/tf"))[1]  # the subscription is live before the grab
            # a grab as the see loop makes it: through the bus, in a thread of its own
            frame = await asyncio.get_running_loop().run_in_executor(None, tapped_call, srv.app.bus, hazcam.grab,
                                                                     "front")
            got: dict[str, Any] = {}
            async with asyncio.timeout(60):
                while len(got) < 2:
                    topic, _, message = await fx.next()
                    if topic in (image_topic, points_topic):
                        got[topic] = message
            return tree, frame, got
        finally:
            await fx.ws.close()
            await session.close()

    tree, frame, got = asyncio.run(live())
    # the frame tree: both cameras of the pair on the rover, where the device's rig puts them
    rig = hazcam.rig("front")
    by_child = {tf.child_frame_id: tf for tf in tree.transforms}
    for side, T in (("left", rig.T_rover_left), ("right", rig.T_rover_right)):
        tf = by_child[f"hazcam_front_{side}"]
        assert tf.parent_frame_id == "rover"
        np.testing.assert_allclose(transform_matrix(tf), T, atol=1e-6)
    # the left image, JPEG in the left camera's frame: the grabbed one
    image = got[image_topic]
    assert image.frame_id == "hazcam_front_left" and image.format == "jpeg"
    decoded_left = cv2.imdecode(np.frombuffer(image.data, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert decoded_left.shape == frame.left.shape and np.abs(decoded_left.astype(float) - frame.left).mean() < 3.0
    # the matched points in the rover frame with each one's range sigma, every one of them
    cloud = got[points_topic]
    assert cloud.frame_id == "rover" and [f.name for f in cloud.fields] == ["x", "y", "z", "sigma_range"]
    packed = np.frombuffer(cloud.data, np.float32).reshape(-1, 4)
    assert len(packed) == len(frame.points) > 10000
    np.testing.assert_array_equal(packed[:, :3], frame.points.astype(np.float32))
    np.testing.assert_array_equal(packed[:, 3], frame.sigma_range.astype(np.float32))


def test_a_channel_is_advertised_once_it_has_something_to_say_and_every_one_advertised_carries_messages(
        server_factory: Any) -> None:
    port = free_port()
    srv = server_factory([f"server.foxglove_port={port}"])
    c = srv.client()

    async def watch() -> tuple[set[str], dict[str, int]]:
        session, fx = await connect(port)
        got: dict[str, int] = {}
        subscribed: set[str] = set()

        async def pump() -> None:  # subscribe to every channel as it is advertised, count its messages
            while True:
                new = [t for t in fx.channels if t not in subscribed]
                if new:
                    subscribed.update(new)
                    await fx.subscribe(*new)
                topic, _, _ = await fx.next(60)
                got[topic] = got.get(topic, 0) + 1

        task = asyncio.create_task(pump())
        try:
            loop = asyncio.get_running_loop()
            for _ in range(2):  # the second round speaks on the channels the first one had advertised
                for line in ("grab-tof -output adv -type amplitude", DEM, "check-move -dx 0.5"):
                    reply = await loop.run_in_executor(None, c.request, line, 120.0)
                    assert reply.status == "OK", reply
            with contextlib.suppress(TimeoutError):  # a safety net: the assertion below says what stayed empty
                async with asyncio.timeout(30):
                    while not set(fx.channels) <= set(got):
                        await asyncio.sleep(0.05)
            return set(fx.channels), got
        finally:
            task.cancel()
            await fx.ws.close()
            await session.close()

    channels, got = asyncio.run(watch())
    assert channels <= set(got), channels - set(got)  # nothing advertised stays empty
    assert {"/tf", "/rover/pose", "/tof/amplitude", "/tof/points", "/map/dem", "/map/hazard", "/nav/check_move",
            "/nav/track", "/rvs/log", "/rvs/job"} <= channels, channels
    # what these commands never make is not advertised: the hazard cameras (none fitted), the
    # layers a ToF DEM has none of, the see loop's bounds, a plan
    never = {"/hazcam/front/points", "/hazcam/front/left/compressed", "/hazcam/rear/points", "/map/intensity",
             "/map/min", "/map/max", "/map/mean", "/map/wmean", "/map/measurement_variance", "/nav/bounds",
             "/nav/plan", "/stereo/left/compressed"}
    assert not channels & never, channels & never


# both names offered: the long suite's (renamed_offer's test below covers the choice by default)
@pytest.mark.parametrize("offered", [("foxglove.websocket.v1",),
                                     pytest.param(("foxglove.websocket.v1", "foxglove.sdk.v1"), marks=long_only())])
def test_a_client_offering_the_old_subprotocol_name_connects_lists_and_decodes(server_factory: Any,
                                                                               offered: tuple[str, ...]) -> None:
    """@foxglove/ws-protocol's FoxgloveClient (Lichtblick, foxglove_bridge's users) offers
    foxglove.websocket.v1 alone: the same protocol, under the name it had before the SDK's. It
    lists every channel, subscribes to them all and decodes a message of each."""
    port = free_port()
    srv = server_factory([f"server.foxglove_port={port}"])
    c = srv.client()
    assert c.request(DEM, timeout=120).status == "OK"

    # what the scan has made (each advertised as it first spoke, in advertise messages of their own)
    made = {"/tf", "/rover/pose", "/rover/truth", "/tof/points", "/tof/depth", "/tof/amplitude", "/map/dem",
            "/map/hazard", "/map/traversability", "/nav/track", "/rvs/log", "/rvs/job"}

    async def live() -> tuple[str | None, set[str], dict[str, Any]]:
        session, fx = await connect(port, offered)
        try:
            await fx.advertised(*made)
            channels = set(fx.channels)
            await fx.subscribe(*channels)
            got: dict[str, Any] = {}
            async with asyncio.timeout(60):
                while not got.keys() >= {"/tf", "/rover/pose", "/map/dem"}:  # the latched and the periodic
                    topic, _, message = await fx.next()
                    got.setdefault(topic, message)
                # what a job says (a scan's frames, the wire) comes with the next one
                again = DEM.replace("-name fx", "-name fx2")  # the first map's files kept to compare with
                job = asyncio.get_running_loop().run_in_executor(None, c.request, again, 120.0)
                while not got.keys() >= channels:
                    topic, _, message = await fx.next()
                    got.setdefault(topic, message)
                assert (await job).status == "OK"
            return fx.ws.protocol, channels, got
        finally:
            await fx.ws.close()
            await session.close()

    protocol, channels, got = asyncio.run(live())
    # the name the client offered, the SDK's when it offered both
    assert protocol == ("foxglove.sdk.v1" if "foxglove.sdk.v1" in offered else "foxglove.websocket.v1")
    assert made <= channels == set(got), channels
    pose = got["/rover/pose"]
    assert pose.frame_id == "world"
    p = srv.app.pose
    assert (pose.pose.position.x, pose.pose.position.y) == pytest.approx((p.x, p.y), abs=1e-6)
    dem, _ = read_geotiff(srv.data / "dem" / "fx_dem.tif")
    np.testing.assert_array_equal(grid_values(got["/map/dem"]), dem)
    assert got["/tof/points"].frame_id == "tof" and len(got["/tof/points"].data) > 16 * 5000
    assert got["/rvs/job"]["command"] == "EGP-RVS-DEM-FULL-TOF"


def test_the_relay_renames_an_offer_of_the_old_name_alone_and_the_answer_back() -> None:
    from rvs_server.telemetry.subprotocol import renamed_answer, renamed_offer

    head = b"GET / HTTP/1.1\r\nHost: x\r\nsec-websocket-protocol: foxglove.websocket.v1\r\n\r\n"
    new, renamed = renamed_offer(head)
    assert renamed and b"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n" in new and b"websocket.v1" not in new
    both = b"GET / HTTP/1.1\r\nSec-WebSocket-Protocol: foxglove.websocket.v1, foxglove.sdk.v1\r\n\r\n"
    assert renamed_offer(both) == (both, False)  # the SDK picks its own name, which the client offered
    other = b"GET / HTTP/1.1\r\nSec-WebSocket-Protocol: chat\r\n\r\n"
    assert renamed_offer(other) == (other, False)  # the SDK refuses it, as it would
    answer = b"HTTP/1.1 101 Switching Protocols\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
    assert renamed_answer(answer) == answer.replace(b"foxglove.sdk.v1", b"foxglove.websocket.v1")
