"""The images of a driver call (drivers.call_images): which arrays of each device call's result
are images and what each one is, for every call that returns some; and the two readers of them,
the telemetry hub (a recording's channels) and the web console's camera panel, agree on every
call: each image the panel shows is the one the hub recorded for that camera."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from support.server import ServerThread

from drivers.call_images import images_of
from drivers.hazcam.device import HazcamFrame
from drivers.replay import Recording
from rvs_server.telemetry.recording import read_messages
from rvs_server.web.cameras import CameraFrames

rng = np.random.default_rng(7)
STATE_TOPICS = {"/tf", "/rover/pose", "/rover/truth", "/raw/calls"}  # every call's, images or not


def tof_image() -> np.ndarray:
    return rng.uniform(0.5, 5.0, (6, 8)).astype(np.float32)


def tof_xyz() -> np.ndarray:
    return rng.uniform(0.5, 5.0, (6, 8, 3)).astype(np.float32)


def camera_image() -> np.ndarray:
    return rng.integers(0, 256, (12, 16), np.uint8)


@dataclass
class Case:
    device: str
    call: str
    args: tuple[Any, ...]
    result: Any
    images: list[tuple[np.ndarray, str, str, str | None]]  # the result's own arrays: (image, what, key, pair)
    topics: set[str]  # the hub's channels of the call's images
    panel: dict[str, tuple[str, str]] = field(default_factory=dict)  # camera -> (the hub's image key, kind)


def cases() -> dict[str, Case]:
    xyz, amplitude = tof_xyz(), tof_image()
    tof = {
        "tof grab_xyz": Case("tof", "grab_xyz", (1, 0.0), (xyz, amplitude),
                             [(xyz, "xyz", "xyz", None), (amplitude, "amplitude", "amplitude", None)],
                             {"/tof/points", "/tof/depth", "/tof/amplitude", "/raw/tof/xyz", "/raw/tof/amplitude"},
                             {"tof_amplitude": ("amplitude", "amplitude"), "tof_depth": ("xyz", "xyz")}),
    }
    for kind, topic in (("amplitude", "/tof/amplitude"), ("distance", "/tof/distance"), ("z", "/tof/depth"),
                        ("confidence", "/tof/confidence"), ("xyz", None)):
        image = tof_xyz() if kind == "xyz" else tof_image()
        shown = {"amplitude": "tof_amplitude", "confidence": None}.get(kind, "tof_depth")
        tof[f"tof grab {kind}"] = Case("tof", "grab", (kind, 4, 0.5), image, [(image, kind, "image", None)],
                                       {"/raw/tof/image"} | ({topic} if topic else set()),
                                       {shown: ("image", kind)} if shown else {})
    distance = tof_image()
    tof["tof grab, no type: distance"] = Case("tof", "grab", (), distance, [(distance, "distance", "image", None)],
                                              {"/tof/distance", "/raw/tof/image"}, {"tof_depth": ("image", "distance")})

    stereo = {}
    for call in ("grab_stereo", "grab_stereo_direct"):
        left, right = camera_image(), camera_image()
        stereo[f"stereo {call}"] = Case(
            "stereo", call, ("1024x768", "mono8"), (left, right),
            [(left, "left", "left", None), (right, "right", "right", None)],
            {"/stereo/left/compressed", "/raw/stereo/left", "/stereo/right/compressed", "/raw/stereo/right"},
            {"stereo_left": ("left", "image")})
    for call, args, side in (("grab_mono", ("left",), "left"), ("grab_mono", ("right", "1024x768"), "right"),
                             ("grab_mono_direct", (), "left")):
        image = camera_image()
        stereo[f"stereo {call} {args}"] = Case(
            "stereo", call, args, image, [(image, side, side, None)],
            {f"/stereo/{side}/compressed", f"/raw/stereo/{side}"},
            {"stereo_left": ("left", "image")} if side == "left" else {})

    left, right = camera_image(), camera_image()
    points = rng.uniform(-2.0, 2.0, (5, 3))
    frame = HazcamFrame("rear", 12.5, points, rng.uniform(0.01, 0.1, 5), np.zeros(3), rng.integers(0, 12, (5, 2)),
                        left, right)
    pair_left, pair_right = camera_image(), camera_image()
    hazcam = {
        "hazcam images": Case("hazcam", "images", ("front",), (pair_left, pair_right),
                              [(pair_left, "left", "front/left", "front"), (pair_right, "right", "front/right", "front")],
                              {"/hazcam/front/left/compressed", "/raw/hazcam/front/left", "/raw/hazcam/front/right"},
                              {"hazcam_front_left": ("front/left", "image")}),
        "hazcam grab": Case("hazcam", "grab", ("rear",), frame,
                            [(left, "left", "rear/left", "rear"), (right, "right", "rear/right", "rear")],
                            {"/hazcam/rear/left/compressed", "/raw/hazcam/rear/left", "/raw/hazcam/rear/right",
                             "/hazcam/rear/points"},
                            {"hazcam_rear_left": ("rear/left", "image")}),
    }
    none = {"ptu move": Case("ptu", "move", (10.0, -20.0, True), (10.0, -20.0), [], set()),
            "rover drive": Case("rover", "drive", (), (1.0, 2.0, 3.0), [], set())}
    return {**tof, **stereo, **hazcam, **none}


CASES = cases()


@pytest.mark.parametrize("name", CASES)
def test_a_calls_images_are_its_results_own_arrays_each_with_what_it_is(name: str) -> None:
    case = CASES[name]
    got = images_of(case.device, case.call, case.args, case.result)
    assert [(i.what, i.key, i.pair) for i in got] == [(what, key, pair) for _, what, key, pair in case.images]
    for image, (want, *_) in zip(got, case.images, strict=True):
        assert image.image is want  # the result's array itself: the reader decides whether to copy


def test_a_result_of_another_shape_raises_what_the_panel_skips() -> None:
    with pytest.raises(ValueError):
        images_of("stereo", "grab_stereo", (), (camera_image(),) * 3)
    with pytest.raises(IndexError):
        images_of("hazcam", "images", (), (camera_image(), camera_image()))
    with pytest.raises(AttributeError):
        images_of("hazcam", "grab", ("front",), (camera_image(), camera_image()))


@pytest.fixture(scope="module")
def published(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Every case's call published once on a recording server's bus, a fresh camera panel
    watching each; the recording's calls and channels, and what each panel kept."""
    srv = ServerThread(tmp_path_factory.mktemp("call_images")).start()
    times, panels = {}, {}
    try:
        c = srv.client()
        assert c.request("record -start -name calls").status == "OK"
        for name, case in CASES.items():
            panels[name] = panel = CameraFrames()
            accept = panel.accept  # one bound method: the bus unsubscribes the very object it was given
            srv.app.bus.subscribe(accept)
            times[name] = time.time_ns()
            srv.app.bus.publish("frame", times[name], device=case.device, call=case.call, args=case.args,
                                result=case.result)
            srv.app.bus.unsubscribe(accept)
        assert c.request("record -stop").fields["dropped"] == "0"
        c.close()
    finally:
        srv.stop()
    path: Path = srv.data / "recordings" / "calls.mcap"
    topics: dict[int, set[str]] = {}
    for _, channel, message in read_messages(path):
        topics.setdefault(message.log_time, set()).add(channel.topic)
    calls = {call.t_ns: call for device_calls in Recording(path).calls.values() for call in device_calls}
    return {"times": times, "panels": panels, "topics": topics, "calls": calls}


@pytest.mark.parametrize("name", CASES)
def test_the_hub_records_and_the_panel_shows_the_same_images_of_each_call(name: str, published: dict[str, Any]) -> None:
    case, t = CASES[name], published["times"][name]
    # the hub: the call's channels, and on /raw each image whole under its key
    topics = published["topics"][t]
    assert "/raw/calls" in topics and topics - STATE_TOPICS == case.topics
    recorded = published["calls"][t].images
    assert sorted(recorded) == sorted(key for _, _, key, _ in case.images)
    for image, _, key, _ in case.images:
        np.testing.assert_array_equal(recorded[key], image)
    # the panel: the cameras it shows, each the image the hub recorded (a depth: the z of the points)
    panel: CameraFrames = published["panels"][name]
    assert {e["name"] for e in panel.listing([]) if "url" in e} == set(case.panel)
    for camera, (key, kind) in case.panel.items():
        frame = panel.latest(camera)
        assert frame.kind == kind
        np.testing.assert_array_equal(frame.image, recorded[key][..., 2] if kind == "xyz" else recorded[key])
