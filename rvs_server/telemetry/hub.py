"""The telemetry hub: takes what the server publishes on its bus, samples the pose and the PTU,
and sends all of it as Foxglove messages to the telemetry process (:mod:`.link`), which encodes
them and logs them to the live server and to a recording.

The hub's thread only picks what is wanted and queues each message's function and arguments for
the link's sender thread. The bus subscriber only queues the item, so the event loop and the
jobs pay a deque append; a queue the thread cannot keep up with drops its oldest items and counts
them (``dropped``), rather than letting a burst of frames grow the server's memory.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections import deque
from typing import TYPE_CHECKING, Any

import numpy as np
import structlog

from drivers.base import DeviceError
from drivers.call_images import CallImage, carries_images, images_of
from prox_workflows.algorithms.transforms import HeadCalibration
from prox_workflows.grid import GridGeometry, Layers

from ..bus import Item
from ..maps import ground_height
from ..protocol import Reply, format_reply
from . import messages as m
from .link import Link
from .outlet import MAP_PREFIX, TOPICS, topic_spec

if TYPE_CHECKING:
    from prox_workflows.algorithms.bounds_map import BoundsMap

    from ..app import App

log = structlog.get_logger("rvs.telemetry")

TICK = 0.1  # s between samples of the frame tree and poses (10 Hz: a PTU sweep looks smooth)
TRACK_EVERY = 1.0  # s between track updates (it grows to thousands of points)
MAX_QUEUED = 512  # items the thread may lag behind (a 24-view scan queues about 50)
BOUNDS_TOPIC = "/nav/bounds"
BOUNDS_EVERY = 10  # see-loop frames between two sends of the bounds map (a replan sends it too)


class Telemetry:
    """The hub: one thread, and the link to the telemetry process once there is one
    (:meth:`attach`). The state the thread keeps (the last maps, plan, check-move) is its own, the
    track the server's (``App.travel``); the process gets it all when it is attached, and each
    change after."""

    def __init__(self, app: App) -> None:
        self.app = app
        self.dropped = 0
        self._queue: deque[Item | tuple[str, Any]] = deque()
        self._wake = threading.Condition()
        self._link: Link | None = None
        self._stop = False
        self._maps: tuple[int, Layers] | None = None
        self._latched: dict[str, tuple[int, Any, tuple[Any, ...]]] = {}  # plan, check-move: their last message
        self._sent: dict[str, int] = {}  # latched topic -> the time of the message the process holds
        self._track_sent = 0.0  # monotonic time of the last send
        self._track_version = -1  # App.travel's version the process holds
        self._state_lock = threading.Lock()  # a state is sampled, stamped and queued in one go: in time order
        self._bounds: tuple[int, BoundsMap] | None = None  # the see loop's bounds map as last published (live)
        self._bounds_items = 0
        self._offered_calls: set[tuple[str, ...]] = set()  # kinds of call passed on while nobody listened
        # roll and pitch (deg) of the rover's last attitude read: the tilt its frames were placed with
        self._attitude: tuple[float, float] | None = None
        self._thread = threading.Thread(target=self._run, name="rvs-telemetry", daemon=True)
        self._thread.start()
        app.bus.subscribe(self.accept)

    # ------------------------------------------------------------------ outside the thread

    def accept(self, item: Item) -> None:
        """The bus subscriber (any thread): queue, return. A frame, only if the process wants it,
        is copied (the job may reuse its arrays) with the PTU and pose it was taken at: the
        grabbing thread holds the PTU still until the call returns, a sample a tick later may not.
        The bounds map goes on as its lower and upper bounds, read in the see loop's thread (it
        fuses the next frame into the same arrays), every :data:`BOUNDS_EVERY` frames and at
        each replan, and only when someone listens; otherwise the hub keeps the map itself."""
        if item.kind == "calling":
            link = self._link
            if link is not None and (link.wants_any() if carries_images(item.data["device"], item.data["call"])
                                     else link.recording):
                self._log_state()  # here, before the call: the frame tree of its start, stamped before it
            return
        if item.kind == "frame":
            if (item.data["device"], item.data["call"]) == ("rover", "attitude") and item.data["result"] is not None:
                self._attitude = (float(item.data["result"][0]), float(item.data["result"][1]))
            link = self._link
            # a call that returns no image (a PTU move) is only for a recording's /raw/calls
            frame = carries_images(item.data["device"], item.data["call"])
            if link is None:
                return
            if not (link.wants_any() if frame else link.recording):
                # nobody listens: the first of its kind still goes, so its topics are offered
                kind = (item.data["device"], item.data["call"], *map(str, item.data["args"][:1]))
                if not frame or kind in self._offered_calls:
                    return
                self._offered_calls.add(kind)
            copied = _copied(item.data["result"])
            item = Item(item.kind, item.time_ns, {**item.data, "result": copied, "state": self._state()})
        elif item.kind == "bounds":
            bounds = item.data["bounds"]
            self._bounds = (item.time_ns, bounds)
            self._bounds_items += 1
            link = self._link
            if link is not None and not link.wants(BOUNDS_TOPIC):
                link.offer(BOUNDS_TOPIC)
            if not (item.data.get("replan") or self._bounds_items % BOUNDS_EVERY == 0) or link is None \
                    or not link.wants(BOUNDS_TOPIC):
                return
            window = bounds_window(bounds)
            if window is None:
                return
            item = Item(item.kind, item.time_ns, {"window": window})
        self._put(item)

    def _put(self, entry: Item | tuple[str, Any]) -> None:
        with self._wake:
            if len(self._queue) >= MAX_QUEUED and isinstance(self._queue[0], Item):  # never an attach or drained
                self._queue.popleft()
                self.dropped += 1
            self._queue.append(entry)
            self._wake.notify()

    def attach(self, link: Link) -> threading.Event:
        """Send to ``link`` from now on, what is latched (maps, plan, check-move, track) first;
        the event is set once that is queued."""
        done = threading.Event()
        with self._wake:  # ahead of the items: the process has the state before what changes it
            self._queue.appendleft(("attach", (link, done)))
            self._wake.notify()
        return done

    def drained(self) -> threading.Event:
        """Set once the thread has sent on every item queued before (a recording stops after
        the reply that ended its last job) and the state sampled once more, the track with it
        (the recording ends where the rover stands)."""
        done = threading.Event()
        self._put(("drained", done))
        return done

    def close(self) -> None:
        self.app.bus.unsubscribe(self.accept)
        with self._wake:
            self._stop = True
            self._wake.notify()
        self._thread.join(5.0)

    # ------------------------------------------------------------------ the thread

    def _run(self) -> None:
        next_tick = time.monotonic()
        while True:
            with self._wake:
                while not self._queue and not self._stop and time.monotonic() < next_tick:
                    self._wake.wait(max(0.0, next_tick - time.monotonic()))
                if self._stop:
                    return
                batch = list(self._queue)
                self._queue.clear()
            for entry in batch:
                try:
                    self._handle(entry)
                except Exception:  # noqa: BLE001 - a bad item costs only itself
                    log.exception("telemetry_item_failed", kind=entry[0] if isinstance(entry, tuple) else entry.kind)
            if time.monotonic() >= next_tick:
                next_tick = time.monotonic() + TICK
                try:
                    self._sample()
                except Exception:  # noqa: BLE001
                    log.exception("telemetry_sample_failed")

    def _handle(self, entry: Item | tuple[str, Any]) -> None:
        if isinstance(entry, tuple):
            what, arg = entry
            if what == "attach":
                self._link, done = arg
                self._sent.clear()
                self._link.on_subscribed = lambda topics: self._put(("resend", topics))
                self._send_latched()
            elif what == "resend":
                self._send_latched(arg)
                return
            else:
                done = arg
                self._sample(track_now=True)
            done.set()
            return
        handler = getattr(self, f"_on_{entry.kind}", None)
        if handler is not None:
            handler(entry)

    def _log(self, topic: str, t_ns: int, encode: Any, *args: Any) -> None:
        """Send ``encode(*args)`` to the process (which encodes it) if ``topic`` is wanted there,
        else offer the topic (the live server advertises it: it has something to say)."""
        link = self._link
        if link is None:
            return
        if link.wants(topic):
            link.log(topic, t_ns, encode, *args)
            if topic_spec(topic).latched:
                self._sent[topic] = t_ns
        else:
            link.offer(topic)

    def _latch(self, topic: str, t_ns: int, encode: Any, *args: Any) -> None:
        self._latched[topic] = (t_ns, encode, args)
        self._log(topic, t_ns, encode, *args)

    def _send_latched(self, topics: frozenset[str] | None = None) -> None:
        """The latched messages (of ``topics``, or all) that the process does not hold yet: it
        keeps what it was sent for the listeners and recordings that come later."""
        def wanted(topic: str, t_ns: int | None) -> bool:
            return (topics is None or topic in topics) and (t_ns is None or self._sent.get(topic) != t_ns)

        if self._maps is not None:
            t_ns, layers = self._maps
            for name in layers.layers:
                if wanted(MAP_PREFIX + name, t_ns):
                    self._log(MAP_PREFIX + name, t_ns, m.grid, t_ns, layers.geometry, {name: layers[name]})
        bounds = self._bounds
        link = self._link
        if bounds is not None and link is not None and link.wants(BOUNDS_TOPIC) and wanted(BOUNDS_TOPIC, bounds[0]) \
                and self._latched.get(BOUNDS_TOPIC, (None,))[0] != bounds[0]:
            # read here, while the see loop may be fusing into it: a cell may be a frame behind its
            # neighbour until the loop's next send, which it reads whole
            window = bounds_window(bounds[1])
            if window is not None:
                self._latch(BOUNDS_TOPIC, bounds[0], m.grid, bounds[0], *window)
        for topic, (t_ns, encode, args) in self._latched.items():
            if wanted(topic, t_ns):
                self._log(topic, t_ns, encode, *args)
        if wanted("/nav/track", None):
            self._send_track()

    def resend(self) -> None:
        """Send what is latched and not yet with the process (a recording starts: it takes all)."""
        self._put(("resend", None))

    # -- bus items

    def _on_maps(self, item: Item) -> None:
        layers: Layers = item.data["layers"]
        self._maps = (item.time_ns, layers)
        for name in layers.layers:
            self._log(MAP_PREFIX + name, item.time_ns, m.grid, item.time_ns, layers.geometry, {name: layers[name]})

    def _on_bounds(self, item: Item) -> None:
        self._latch(BOUNDS_TOPIC, item.time_ns, m.grid, item.time_ns, *item.data["window"])

    def _on_frame(self, item: Item) -> None:
        t, device, result = item.time_ns, item.data["device"], item.data["result"]
        self._log_call(item)
        images = images_of(device, item.data["call"], item.data["args"], result)
        if device == "tof":
            self._on_tof(t, images)
        elif device == "stereo":
            for image in images:
                frame = m.sensor_frame(image.what)
                self._log(f"/stereo/{image.what}/compressed", t, m.jpeg, t, frame, image.image)
                self._log(f"/raw/stereo/{image.key}", t, m.raw_image, t, frame, image.image)
        elif images:  # a hazcam pair's
            self._on_hazcam(t, images, result)

    def _on_tof(self, t: int, images: list[CallImage]) -> None:
        """A ``grab_xyz`` goes out as its points, their depth and amplitude; a ``grab`` as its
        image on the topic of its type, if there is one."""
        by_key = {image.key: image.image for image in images}
        if "xyz" in by_key:
            xyz, amplitude = by_key["xyz"], by_key["amplitude"]
            self._log("/tof/points", t, m.point_cloud, t, "tof", xyz, amplitude)
            self._log("/tof/depth", t, m.depth, t, "tof", xyz)
            self._log("/tof/amplitude", t, m.raw_image, t, "tof", amplitude)
        else:
            for image in images:
                topic = {"z": "/tof/depth"}.get(image.what, f"/tof/{image.what}")
                if topic in TOPICS:
                    self._log(topic, t, m.raw_image, t, "tof", image.image)
        for image in images:
            self._log(f"/raw/tof/{image.key}", t, m.raw_image, t, "tof", image.image)

    def _on_hazcam(self, t: int, images: list[CallImage], result: Any) -> None:
        """A body hazard camera pair's grab (a HazcamFrame: images and matched points, in the
        rover frame) or its ``images(pair)`` (the two images alone)."""
        for image in images:
            frame = m.hazcam_frame(image.pair, image.what)
            if image.what == "left":
                self._log(f"/hazcam/{image.pair}/left/compressed", t, m.jpeg, t, frame, image.image)
            self._log(f"/raw/hazcam/{image.key}", t, m.raw_image, t, frame, image.image)
        if not isinstance(result, tuple):
            self._log(f"/hazcam/{images[0].pair}/points", t, m.cloud, t, "rover", result.points, result.sigma_range,
                      "sigma_range")

    def _log_call(self, item: Item) -> None:
        """The call on /raw/calls, ahead of its frames (a replay serves them for it): its
        arguments, a result that is no image (a PTU's position), where the PTU and the rover were."""
        pose, ptu, _ = item.data["state"]
        result = item.data["result"]
        images = isinstance(result, np.ndarray) and result.ndim >= 2 or isinstance(result, tuple) and any(
            isinstance(r, np.ndarray) and r.ndim >= 2 for r in result)
        self._log("/raw/calls", item.time_ns, m.json_bytes, {
            "device": item.data["device"], "call": item.data["call"], "args": _plain(item.data["args"]),
            "result": None if images else _plain(result), "ptu": ptu, "pose": list(pose[:3])})

    def _wire(self, item: Item, direction: str, conn: Any, text: str, reply: Reply | None = None) -> None:
        t = item.time_ns
        status, kind = (reply.status, str(reply.fields.get("kind", ""))) if reply is not None else ("", "")
        self._log("/rvs/log", t, m.log_line, t, direction, conn, text, status, kind)
        self._log("/rvs/wire", t, m.json_bytes, {"dir": direction, "conn": conn, "line": text})

    def _on_request(self, item: Item) -> None:
        line = item.data["line"].decode("utf-8", "replace").rstrip("\r\n")
        self._wire(item, "request", item.data["conn"], line)

    def _on_reply(self, item: Item) -> None:
        reply = item.data["reply"]
        self._wire(item, "reply", item.data["conn"], format_reply(reply), reply)
        fields = reply.fields
        # a job's own lines only: ``status -job N`` names job N too, but is no line of it
        if item.data.get("job") and isinstance(fields.get("job"), int):
            done, total = int(fields.get("done", 0)), int(fields.get("total", 0))
            progress = {"job": int(fields["job"]), "command": reply.module, "status": reply.status,
                        "phase": str(fields.get("phase", "")), "done": done, "total": total,
                        "fraction": done / total if total else float(reply.status == "OK"),
                        "message": str(fields.get("message", ""))}
            self._log("/rvs/job", item.time_ns, m.json_bytes, progress)
        check = self.app.travel.check
        if reply.module == "EGP-RVS-CHECK-MOVE" and reply.status == "OK" and check is not None:
            head = self.app.config.get("head")
            z = ground_height(self.app.maps.layers, check.start[0], check.start[1])
            self._latch("/nav/check_move", item.time_ns, m.check_move, item.time_ns, check.start, dict(check.fields),
                        z, (head.rover_length, head.rover_width))

    def _on_event(self, item: Item) -> None:
        reply = item.data["reply"]
        self._wire(item, "event", None, format_reply(reply), reply)
        fields = reply.fields
        if fields.get("kind") == "waiting" and fields.get("waypoints"):
            waypoints = [(float(x), float(y), float(h)) for x, y, h in fields["waypoints"]]
            z = ground_height(self.app.maps.layers, waypoints[0][0], waypoints[0][1])
            self._latch("/nav/plan", item.time_ns, m.plan, item.time_ns, waypoints, z, fields.get("leg"))

    # -- sampled state

    def _state(self) -> tuple[tuple[float, ...], tuple[float, float] | None, tuple[float, ...] | None]:
        """The believed pose (x, y, heading, ground z, roll, pitch), the PTU and the simulated true
        pose (x, y, heading, roll, pitch) now. The roll and pitch are the GNC's where its pose
        report gave them, else the rover's last attitude read (which the frames were placed
        with; the hub reads no device itself, so a replay's recorded reads stay the frames'),
        else level."""
        app = self.app
        pose = app.pose
        truth = None
        if app.world is not None:
            tr = app.world.truth()
            truth = tuple(float(tr[k]) for k in ("x", "y", "heading", "roll", "pitch"))
        if pose.roll is not None and pose.pitch is not None:
            roll, pitch = pose.roll, pose.pitch
        else:
            roll, pitch = self._attitude or (0.0, 0.0)
        z = ground_height(app.maps.layers, pose.x, pose.y)
        return (pose.x, pose.y, pose.heading, z, roll, pitch), app.ptu_position(), truth

    def _log_state(self) -> None:
        """The frame tree and the poses as they are now, stamped now: from the hub's thread every
        tick and from a device call's thread as it starts (the tree a frame is seen through).
        Sampled, stamped and queued under one lock, so the pose channels never step back in time
        and each pose is stamped with the time it describes (a player would show the rover
        jumping)."""
        head = HeadCalibration.from_dict(self.app.config.get("head").as_dict())
        body = self._body_frames()
        with self._state_lock:
            t, (pose, ptu, truth) = time.time_ns(), self._state()
            self._log("/tf", t, m.frame_tree, t, head, pose, ptu, truth, body)
            self._log("/rover/pose", t, m.pose_in_world, t, *pose)
            if truth is not None:
                self._log("/rover/truth", t, m.pose_in_world, t, *truth[:3], pose[3], *truth[3:])

    def _body_frames(self) -> list[tuple[str, np.ndarray]]:
        """The optical frames of the hazard camera pairs switched on, in the rover frame, where
        the device declares them (none while it is off or not open)."""
        hazcam = self.app.devices.devices.get("hazcam")
        frames: list[tuple[str, np.ndarray]] = []
        for pair in hazcam.cameras() if hazcam is not None else ():
            try:
                rig = hazcam.rig(pair)
            except (DeviceError, KeyError):  # not open (yet)
                continue
            frames += [(m.hazcam_frame(pair, "left"), rig.T_rover_left), (m.hazcam_frame(pair, "right"),
                                                                           rig.T_rover_right)]
        return frames

    def _sample(self, track_now: bool = False) -> None:
        if self._link is None:
            return
        self._log_state()
        if self.app.travel.version != self._track_version and (
                track_now or time.monotonic() - self._track_sent >= TRACK_EVERY):
            self._send_track()

    def _send_track(self) -> None:
        """The server's track (``App.travel``), a little above the ground it was driven on."""
        self._track_version, self._track_sent = self.app.travel.version, time.monotonic()
        points = np.array(self.app.travel.track(), float).reshape(-1, 3)
        points[:, 2] += 0.02
        t = time.time_ns()
        self._log("/nav/track", t, m.track, t, points)


def bounds_window(bounds: BoundsMap) -> tuple[GridGeometry, dict[str, np.ndarray]] | None:
    """The bounds map's lower and upper bounds over the box of its bounded cells (the mission's
    grid round them holds none), with that box's grid; None while no cell has a bound."""
    bounded = bounds.bounded()
    rows, cols = np.flatnonzero(bounded.any(axis=1)), np.flatnonzero(bounded.any(axis=0))
    if not len(rows):
        return None
    g = bounds.geometry
    lower, upper, box = bounds.window(g.xmin + cols[0] * g.cell, g.ymax - (rows[-1] + 1) * g.cell,
                                      g.xmin + (cols[-1] + 1) * g.cell, g.ymax - rows[0] * g.cell)
    return box, {"lower": lower, "upper": upper}


def _copied(result: Any) -> Any:
    """A call's result with its arrays copied; a frame object (a hazcam's) field by field."""
    if isinstance(result, tuple):
        return tuple(np.array(a) for a in result)
    if dataclasses.is_dataclass(result) and not isinstance(result, type):
        return dataclasses.replace(result, **{f.name: np.array(getattr(result, f.name))
                                              for f in dataclasses.fields(result)
                                              if isinstance(getattr(result, f.name), np.ndarray)})
    return np.array(result)


def _plain(value: Any) -> Any:
    """A call's arguments or result as JSON takes them (a PTU's position comes as numpy
    scalars); of a frame object (a hazcam's), the fields that are no array (its pair, time stamp
    and how long its capture took); any other object (a drive's pilot, which holds the job) by
    its type's name."""
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)
                if not isinstance(getattr(value, f.name), np.ndarray)}
    if isinstance(value, np.ndarray | np.generic):
        return value.tolist()
    return value if value is None or isinstance(value, str | int | float | bool) else type(value).__name__
