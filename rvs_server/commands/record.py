"""record: an MCAP recording of the run (docs/PROTOCOL.md, Foxglove and MCAP)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from ..app import Context
from ..config import ModuleConfig, param
from ..protocol import Fixed, ProtocolError
from ..table import ALWAYS, command
from ..telemetry import RECORDINGS
from ..telemetry.recording import PROFILES


@dataclass
class RecordConfig(ModuleConfig):
    module: ClassVar[str] = "record"
    start: bool = param(False, f"start recording to {RECORDINGS}/<name>.mcap under the data directory (ros2: "
                        f"the rosbag2 directory {RECORDINGS}/<name>/)")
    stop: bool = param(False, "stop recording and finish the file")
    name: str = param("", "stem of the recording (default rvs_<UTC time>)", stem=True)
    profile: str = param("foxglove", "what the messages are: Foxglove's schemas, or ROS 2 messages (CDR) that "
                         "ros2 bag plays (a rosbag2 directory); also the profile server.record records in", choices=tuple(PROFILES))


@command("record", klass=ALWAYS, config=RecordConfig,
         help="record the run to MCAP (every Foxglove topic, the devices' raw frames, the wire lines): "
              "-start [-name N] [-profile ros2], -stop; without options, whether it records")
async def record(ctx: Context, cfg: RecordConfig) -> dict[str, Any]:
    station = ctx.app.telemetry
    if station is None:
        raise ProtocolError("E_STATE", "telemetry is not running (the server is starting or stopping); try again")
    given = {k for k, _ in ctx.request.options}
    if cfg.start and cfg.stop:
        raise ProtocolError("E_ARG", "give -start or -stop, not both")
    if given & {"name", "profile"} and not cfg.start:
        raise ProtocolError("E_ARG", f"-{sorted(given & {'name', 'profile'})[0]} goes with -start")
    if cfg.start:
        return await station.start_recording(cfg.name, cfg.profile)
    if cfg.stop:
        out = await station.stop_recording()
        out["seconds"] = Fixed(out["seconds"], 1)
        return out
    return {"recording": station.fields()["recording"]}
