"""The body hazard cameras in recordings: with the pairs on, the frame tree carries each camera's
optical frame on the rover where the device declares it, a grab goes out as its left image and
its matched points, and the raw pair is recorded whole; the hazcams' replay backend serves those
pairs again, matched into the same points, and says what it cannot answer. A call whose
arguments do not pickle (a drive's pilot) is recorded all the same, the argument by its type."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest
from support.mcap import decoded, transform_matrix
from support.server import ServerThread

import drivers.hazcam
from drivers.base import DeviceError
from rvs_server.bus import tapped_call
from rvs_server.devices import stereo_points


class Pilot:
    def __init__(self, emit: Any) -> None:
        self.emit = emit


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A server with both pairs on records a grab of the front pair, then one of the rear."""
    srv = ServerThread(tmp_path_factory.mktemp("hazcam"), ["drivers.hazcam.cameras=front,rear"]).start()
    try:
        c = srv.client()
        assert c.request("record -start -name hz").status == "OK"
        hazcam = srv.app.devices.get("hazcam")
        frames = [tapped_call(srv.app.bus, hazcam.grab, pair) for pair in ("front", "rear")]
        # a drive's call, whose pilot holds what does not pickle (the job's callbacks)
        pilot = Pilot(lambda: None)
        srv.app.bus.publish("frame", device="rover", call="drive", args=(pilot,), result=(1.0, 2.0, 3.0))
        assert c.request("record -stop").fields["dropped"] == "0"
        rigs = {pair: hazcam.rig(pair) for pair in ("front", "rear")}
        c.close()
    finally:
        srv.stop()
    return {"path": srv.data / "recordings" / "hz.mcap", "frames": frames, "rigs": rigs}


def test_hazcam_frames_images_and_points_are_recorded(recorded: dict[str, Any]) -> None:
    messages = decoded(recorded["path"])
    front, rear = recorded["frames"]
    assert len(front.points) > 10000 and len(rear.points) > 10000  # ground matched, not an empty grab

    # the frame tree: each camera's optical frame on the rover, as the device's rig declares it
    tree = next(m for topic, _, m in messages if topic == "/tf")
    by_child = {tf.child_frame_id: tf for tf in tree.transforms}
    for pair, rig in recorded["rigs"].items():
        for side, T in (("left", rig.T_rover_left), ("right", rig.T_rover_right)):
            tf = by_child[f"hazcam_{pair}_{side}"]
            assert tf.parent_frame_id == "rover"
            np.testing.assert_allclose(transform_matrix(tf), T, atol=1e-6)

    for frame in (front, rear):
        pair = frame.camera
        # the live left image: JPEG in the left camera's frame
        image = [m for topic, _, m in messages if topic == f"/hazcam/{pair}/left/compressed"]
        assert len(image) == 1 and image[0].frame_id == f"hazcam_{pair}_left" and image[0].format == "jpeg"
        jpeg = cv2.imdecode(np.frombuffer(image[0].data, np.uint8), cv2.IMREAD_GRAYSCALE)
        assert jpeg.shape == frame.left.shape and np.abs(jpeg.astype(float) - frame.left).mean() < 3.0
        # the matched points in the rover frame, each with its range sigma
        cloud = [m for topic, _, m in messages if topic == f"/hazcam/{pair}/points"]
        assert len(cloud) == 1 and cloud[0].frame_id == "rover"
        assert [f.name for f in cloud[0].fields] == ["x", "y", "z", "sigma_range"]
        packed = np.frombuffer(cloud[0].data, np.float32).reshape(-1, 4)
        np.testing.assert_array_equal(packed[:, :3], frame.points.astype(np.float32))
        np.testing.assert_array_equal(packed[:, 3], frame.sigma_range.astype(np.float32))
        # the raw pair, whole, for a replay, after its call
        for side, want in (("left", frame.left), ("right", frame.right)):
            raw = [m for topic, _, m in messages if topic == f"/raw/hazcam/{pair}/{side}"]
            assert len(raw) == 1 and raw[0].encoding == "mono8" and raw[0].frame_id == f"hazcam_{pair}_{side}"
            np.testing.assert_array_equal(np.frombuffer(raw[0].data, np.uint8).reshape(want.shape), want)
    calls = [m for topic, _, m in messages if topic == "/raw/calls"]
    assert [(c["device"], c["call"], c["args"], c["result"]) for c in calls] == [
        *(("hazcam", "grab", [f.camera], {"camera": f.camera, "stamp": f.stamp, "capture_s": f.capture_s,
                                          "capture_cpu_s": f.capture_cpu_s}) for f in (front, rear)),
        ("rover", "drive", ["Pilot"], [1.0, 2.0, 3.0])]


def test_the_hazcam_replay_serves_the_recorded_pairs_and_says_what_it_cannot(recorded: dict[str, Any]) -> None:
    front, rear = recorded["frames"]
    hazcam = drivers.hazcam.create({"backend": "replay", "cameras": "front,rear",
                                    "replay_file": str(recorded["path"])}, matcher=stereo_points)
    hazcam.open()
    # the first recorded grab is the front pair's: a grab of the rear pair there has nothing to serve
    with pytest.raises(DeviceError, match="was a grab of the front pair; this grab asks for the rear pair"):
        hazcam.grab("rear")
    again = hazcam.grab("rear")  # the next recorded grab is the rear pair's: served and matched again
    np.testing.assert_array_equal(again.left, rear.left)
    np.testing.assert_array_equal(again.right, rear.right)
    np.testing.assert_array_equal(again.points, rear.points)
    assert again.stamp == rear.stamp
    with pytest.raises(DeviceError, match="holds 2 hazcam frame call.s. and all were served"):
        hazcam.grab("front")
    hazcam.close()


def test_a_replayed_hazcam_without_a_recording_is_e_device(server_factory: Any) -> None:
    srv = server_factory(["drivers.hazcam.cameras=front", "drivers.hazcam.backend=replay"])
    reinit = srv.client().request("reinit -device hazcam", timeout=60)
    assert reinit.fields["code"] == "E_DEVICE" and "drivers.hazcam.replay_file" in reinit.fields["message"], reinit
