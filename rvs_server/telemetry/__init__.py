"""Foxglove live and MCAP recordings: the hub (:mod:`.hub`) turns what the server publishes on
its bus into Foxglove messages and sends them to the telemetry process (:mod:`.link`,
:mod:`.worker`), where the live server (:mod:`.live`) and a recording (:mod:`.recording`) are.
Topics, schemas and frame ids: docs/PROTOCOL.md."""

from __future__ import annotations

import asyncio
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Any

import structlog

from ..protocol import ProtocolError
from .facts import replay_facts
from .hub import Telemetry
from .link import Link, TelemetryError

if TYPE_CHECKING:
    from ..app import App

log = structlog.get_logger("rvs.telemetry")

RECORDINGS = "recordings"  # under the data directory
ATTACH_S = 30.0  # for the hub to queue what is latched to a new telemetry process, or what it has to send


class Station:
    """What the server runs of telemetry: the hub and the telemetry process (started with the
    server when Foxglove is on, else at the first recording), what status says of them and the
    recording in progress. Event loop only; the blocking parts run in its executor."""

    def __init__(self, app: App) -> None:
        self.app = app
        self.hub = Telemetry(app)
        self.link: Link | None = None
        self.live_off: str | None = "server.foxglove_port is 0"
        self.recording: Path | None = None
        self._host = "127.0.0.1"
        self._busy = False  # a record -start or -stop is under way
        self._dropped_at_start = 0

    async def start(self, host: str) -> None:
        """The Foxglove server (a port taken costs only Foxglove, as for the console), then the
        recording ``server.record`` asks for."""
        self._host = host
        cfg = self.app.server_cfg
        if cfg.foxglove_port:
            try:
                await self._connect()
            except TelemetryError as exc:
                self.live_off = f"the telemetry process did not start ({exc})"
                log.warning("foxglove_off", reason=self.live_off)
        if cfg.record:
            await self.start_recording("", self.app.config.get("record").profile)

    async def _connect(self) -> Link:
        """A telemetry process (a new one if there is none or it exited), with the hub attached."""
        if self.link is not None and self.link.exited is None:
            return self.link
        loop = asyncio.get_running_loop()
        link = await loop.run_in_executor(None, Link, self._host, self.app.server_cfg.foxglove_port, self.app.name)
        await loop.run_in_executor(None, self.hub.attach(link).wait, ATTACH_S)
        self.link = link
        self.live_off = link.live_off
        if link.url is not None:
            log.info("foxglove", url=link.url)
        elif self.app.server_cfg.foxglove_port:
            log.warning("foxglove_off", reason=self.live_off)
        return link

    def dropped(self) -> int:
        """Messages lost to a recording: bus items the hub fell behind on, messages the telemetry
        process's queue had no room for."""
        return self.hub.dropped + (self.link.dropped if self.link is not None else 0)

    async def start_recording(self, name: str, profile: str) -> dict[str, Any]:
        """Record to ``recordings/<name>.mcap`` in ``profile`` (one of :data:`.recording.PROFILES`)."""
        if self.recording is not None or self._busy:
            where = self.app.rel(self.recording) if self.recording is not None else "a file"
            raise ProtocolError("E_STATE", f"already recording to {where}; send record -stop first")
        name = name or "rvs_" + datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
        # ros2: a rosbag2 directory (the bag, named by the directory) holding <name>_0.mcap
        shown = self.app.data_path(RECORDINGS, name if profile == "ros2" else f"{name}.mcap")
        if shown.exists():
            raise ProtocolError("E_ARG", f"{self.app.rel(shown)} exists; choose another -name")
        path = self.app.data_path(RECORDINGS, name, f"{name}_0.mcap") if profile == "ros2" else shown
        metadata = {"server": self.app.name, "started": datetime.now(UTC).isoformat(),
                    "scene": self.app.world.scene_name if self.app.world is not None else ""}
        self._busy = True
        link = None
        try:
            metadata.update(await asyncio.get_running_loop().run_in_executor(None, replay_facts, self.app))
            link = await self._connect()
            link.recording = True  # from here every message goes, and is kept when the process lags
            await asyncio.get_running_loop().run_in_executor(None, link.call, "record_start", path, metadata, profile)
            self.hub.resend()  # what is latched and the process never got (nobody listened)
        except TelemetryError as exc:
            if link is not None:
                link.recording = False
            raise ProtocolError("E_IO", f"{self.app.rel(path)} could not be recorded: {exc}") from None
        finally:
            self._busy = False
        self.recording = shown
        self._dropped_at_start = self.dropped()
        log.info("recording_started", file=self.app.rel(shown))
        return {"recording": self.app.rel(shown)}

    async def stop_recording(self) -> dict[str, Any]:
        path, link = self.recording, self.link
        if path is None or link is None:
            raise ProtocolError("E_STATE", "not recording; send record -start [-name N] first")
        self.recording = None
        loop = asyncio.get_running_loop()
        await loop.run_in_executor(None, self.hub.drained().wait, ATTACH_S)
        link.recording = False
        try:
            summary = await loop.run_in_executor(None, link.call, "record_stop")
        except TelemetryError as exc:
            raise ProtocolError("E_IO", f"{self.app.rel(path)} was not finished ({exc}); it holds what was "
                                        "written up to a second before") from None
        log.info("recording_stopped", file=self.app.rel(path), **summary)
        return {"file": self.app.rel(path), **summary, "dropped": self.dropped() - self._dropped_at_start}

    def fields(self) -> dict[str, Any]:
        """What status says: where Foxglove is (or why not) and what it could not keep up with,
        the recording in progress and what it lost."""
        link = self.link
        if link is not None and link.live:
            out: dict[str, Any] = {"foxglove": "on", "foxglove_url": link.url, "foxglove_dropped": link.live_dropped}
        else:
            reason = link.exited if link is not None and link.exited else self.live_off
            out = {"foxglove": "off", "foxglove_reason": reason}
        out["recording"] = self.app.rel(self.recording) if self.recording is not None else None
        if self.recording is not None:
            out["recording_dropped"] = self.dropped() - self._dropped_at_start
        return out

    async def close(self) -> None:
        """Server shutdown: the recording is finished (its summary written), the process stopped."""
        loop = asyncio.get_running_loop()
        if self.recording is not None:
            try:
                await self.stop_recording()
            except ProtocolError as exc:
                log.warning("recording_lost", reason=exc.message)
        await loop.run_in_executor(None, self.hub.close)
        if self.link is not None:
            await loop.run_in_executor(None, self.link.close)
