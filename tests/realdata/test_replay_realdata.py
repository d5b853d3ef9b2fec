"""A real stereo pair through the replay path: the Middlebury 2014 Motorcycle pair (shipped in
scikit-image, so this runs in CI) becomes a device recording (the pair as a triggered grab of
the PIKE cameras at 640 x 480, cropped, with its own calibration); a server on replay backends
serves it to a grab-stereo and a stereo DEM and records that run; rvs-replay then runs the
recorded run again with the same replies and the same maps cell for cell."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from foxglove.messages import RawImage, Timestamp

from prox_workflows.grid import read_geotiff
from rvs_server.client.recording_replay import replay, replay_sets

# skimage.data.stereo_motorcycle's docstring: the quarter-size pair's calibration
FOCAL, CX, CY, DOFFS, BASELINE = 994.978, 311.193, 254.877, 31.086, 0.193001
CROP = (10, 50)  # rows, columns cut off the top and the left: 741 x 500 -> 640 x 480 ("low")
START_PTU = [0.0, -20.0]


def motorcycle() -> tuple[np.ndarray, np.ndarray]:
    data = pytest.importorskip("skimage.data", reason="scikit-image (the test extra) ships the Motorcycle pair")
    left, right, _ = data.stereo_motorcycle()
    r, c = CROP
    return tuple(cv2.cvtColor(im, cv2.COLOR_RGB2GRAY)[r:r + 480, c:c + 640].copy() for im in (left, right))


def device_recording(path: Path, left: np.ndarray, right: np.ndarray, grabs: int) -> None:
    """An MCAP as a server records it, holding only what the replay backends read: the stereo
    calibration and the start in the metadata, ``grabs`` triggered grabs of the pair."""
    from mcap.writer import Writer

    K1 = [[FOCAL, 0, CX - CROP[1]], [0, FOCAL, CY - CROP[0]], [0, 0, 1]]
    K2 = [[FOCAL, 0, CX + DOFFS - CROP[1]], [0, FOCAL, CY - CROP[0]], [0, 0, 1]]
    calib = {"K1": K1, "D1": [0.0] * 5, "K2": K2, "D2": [0.0] * 5, "R": np.eye(3).tolist(),
             "T": [-BASELINE, 0.0, 0.0], "image_size": [640, 480], "source": "Middlebury 2014 Motorcycle"}
    schema = RawImage.get_schema()
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        w.add_metadata("rvs", {"server": "realdata", "ptu": json.dumps(START_PTU), "pose": "[0, 0, 0]",
                               "stereo_calibration": json.dumps({"low": calib})})
        raw = w.register_channel("/raw/calls", "json", 0)
        image_schema = w.register_schema(schema.name, schema.encoding, schema.data)
        sides = {s: w.register_channel(f"/raw/stereo/{s}", "protobuf", image_schema) for s in ("left", "right")}
        for i in range(grabs):
            t = 1_700_000_000_000_000_000 + i * 1_000_000_000
            call = {"device": "stereo", "call": "grab_stereo", "args": ["low", "mono8"], "result": None,
                    "ptu": None, "pose": [0, 0, 0]}  # real data: the pointing it was taken at is not known
            w.add_message(raw, t, json.dumps(call).encode(), t)
            for side, image in (("left", left), ("right", right)):
                msg = RawImage(timestamp=Timestamp(t // 10**9, t % 10**9), frame_id=f"stereo_{side}", width=640,
                               height=480, encoding="mono8", step=640, data=image.tobytes())
                w.add_message(sides[side], t, msg.encode(), t)
        w.finish()


RUN = ["grab-stereo -output moto -resolution low", "dem-full -sensor stereo -range 0,0,-20,-20 -name moto"]


def test_the_motorcycle_pair_replays_through_grab_stereo_and_a_stereo_dem(server_factory: Any,
                                                                          tmp_path: Path) -> None:
    left, right = motorcycle()
    source = tmp_path / "motorcycle_device.mcap"
    device_recording(source, left, right, grabs=2)
    sets = [s for s in replay_sets(source, Path("unused"), "fast") if not s.startswith(("server.data", "server.port"))]
    srv = server_factory(sets)
    c = srv.client()
    assert c.request("record -start -name moto").status == "OK"
    replies = [c.request(line, timeout=120) for line in RUN]
    assert all(r.status == "OK" for r in replies), replies
    assert c.request("record -stop").status == "OK"
    # the real pixels went through: the grab wrote the recorded left image
    grabbed = cv2.imread(str(srv.data / replies[0].fields["left"]), cv2.IMREAD_UNCHANGED)
    assert grabbed is not None and np.array_equal(grabbed, left)
    assert int(replies[1].fields["cells"]) > 1000, replies[1]

    run = srv.data / "recordings" / "moto.mcap"
    out = replay(run, tmp_path / "replay", products=True)
    assert out.problems == [] and out.sent == len(RUN) and out.maps >= 9, out
    want, g1 = read_geotiff(srv.data / "dem" / "moto_dem.tif")
    got, g2 = read_geotiff(tmp_path / "replay" / "dem" / "moto_dem.tif")
    assert g1 == g2 and np.array_equal(want, got, equal_nan=True)
