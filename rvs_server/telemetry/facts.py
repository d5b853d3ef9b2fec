"""What a replay needs from a recording that no message carries, written into the recording's
metadata (beside the server's name and scene) at its start: the configuration the run had, where the PTU and the rover
stood, and the calibrations the devices report (the ToF's camera matrix, the stereo pair's
calibration at each resolution), and the current maps' name, files and exact grid (their
cells are the /map/* Grids a recording starts with). A replay backend (drivers/replay.py) serves them in place of
the hardware or the simulated world that gave them."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

from drivers.base import DeviceError
from drivers.stereo.modes import RESOLUTIONS

if TYPE_CHECKING:
    from ..app import App

def replay_facts(app: App) -> dict[str, str]:
    """The metadata's replay entries, each value JSON. Blocking (a camera's lock): off the event loop."""
    pose = app.pose
    facts: dict[str, Any] = {
        "config": {name: app.config.get(name).as_dict() for name in app.config.module_names()},
        "ptu": app.ptu_position(),
        "pose": [pose.x, pose.y, pose.heading],
        "pose_estimate": [pose.source, pose.sigma, pose.sigma_heading],
    }
    layers = app.maps.layers
    if layers is not None:  # the current maps' cells are the latched /map/* Grids; their grid exactly here
        g = layers.geometry
        facts["maps"] = {"name": app.maps.name, "files": app.maps.files(),
                         "geometry": [g.cell, g.xmin, g.ymax, g.width, g.height, g.crs]}
    devices = app.devices.devices
    tof = devices.get("tof")
    if tof is not None:
        K, dist = tof.intrinsics()
        facts["tof_intrinsics"] = {"K": K.tolist(), "dist": dist.tolist()}
    stereo = devices.get("stereo")
    if stereo is not None:
        calibrations = {}
        for resolution in RESOLUTIONS:
            try:
                calib = stereo.calibration(resolution)
            except (DeviceError, OSError, ValueError):  # no calibration configured: a replay has none either
                continue
            calibrations[resolution] = {k: _plain(v) for k, v in calib.items()}
        facts["stereo_calibration"] = calibrations
    return {key: json.dumps(value, default=_plain) for key, value in facts.items()}


def _plain(value: Any) -> Any:
    return value.tolist() if hasattr(value, "tolist") else value
