"""Foxglove live and MCAP recordings: the hub (:mod:`.hub`) turns what the server publishes on
its bus into Foxglove messages; the live server (:mod:`.live`) and a recording
(:mod:`.recording`) are where they go. Topics, schemas and frame ids: docs/PROTOCOL.md."""

from __future__ import annotations

import asyncio
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

import structlog

from ..protocol import ProtocolError
from .hub import Telemetry
from .live import LiveOutlet
from .recording import Recording

if TYPE_CHECKING:
    from ..app import App

log = structlog.get_logger("rvs.telemetry")

RECORDINGS = "recordings"  # under the data directory


class Station:
    """What the server runs of telemetry: the hub, the live server (or why there is none) and
    the recording in progress. Event loop only; the blocking parts run in its executor."""

    def __init__(self, app: App) -> None:
        self.app = app
        self.hub = Telemetry(app)
        self.live: LiveOutlet | None = None
        self.live_off: str | None = "server.foxglove_port is 0"
        self.recording: Recording | None = None
        self._busy = False  # a record -start or -stop is under way

    async def start(self, host: str) -> None:
        """The live server (a port taken costs only Foxglove, as for the console), then the
        recording ``server.record`` asks for."""
        cfg = self.app.server_cfg
        loop = asyncio.get_running_loop()
        if cfg.foxglove_port:
            try:
                self.live = await loop.run_in_executor(None, LiveOutlet, self.hub, host, cfg.foxglove_port, self.app.name)
                self.live_off = None
                log.info("foxglove", url=self.live.url)
            except RuntimeError as exc:
                self.live_off = f"Foxglove port {host}:{cfg.foxglove_port} could not be served ({exc})"
                log.warning("foxglove_off", reason=self.live_off)
        if cfg.record:
            await self.start_recording("")

    async def start_recording(self, name: str) -> dict[str, Any]:
        if self.recording is not None or self._busy:
            where = self.app.rel(self.recording.path) if self.recording is not None else "a file"
            raise ProtocolError("E_STATE", f"already recording to {where}; send record -stop first")
        name = name or "rvs_" + datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
        path = self.app.data_path(RECORDINGS, f"{name}.mcap")
        if path.exists():
            raise ProtocolError("E_ARG", f"{self.app.rel(path)} exists; choose another -name")
        metadata = {"server": self.app.name, "started": datetime.now(UTC).isoformat(),
                    "scene": self.app.world.scene_name if self.app.world is not None else ""}
        self._busy = True
        try:
            self.recording = await asyncio.get_running_loop().run_in_executor(
                None, Recording, self.hub, path, metadata)
        finally:
            self._busy = False
        log.info("recording_started", file=self.app.rel(path))
        return {"recording": self.app.rel(path)}

    async def stop_recording(self) -> dict[str, Any]:
        recording = self.recording
        if recording is None:
            raise ProtocolError("E_STATE", "not recording; send record -start [-name N] first")
        self.recording = None
        summary = await asyncio.get_running_loop().run_in_executor(None, recording.close)
        log.info("recording_stopped", file=self.app.rel(recording.path), **summary)
        return {"file": self.app.rel(recording.path), **summary, "dropped": self.hub.dropped}

    def fields(self) -> dict[str, Any]:
        """What status says: where Foxglove is (or why not), and the recording in progress."""
        out: dict[str, Any] = {"foxglove": "on", "foxglove_url": self.live.url} if self.live is not None else {
            "foxglove": "off", "foxglove_reason": self.live_off}
        out["recording"] = self.app.rel(self.recording.path) if self.recording is not None else None
        return out

    async def close(self) -> None:
        """Server shutdown: the recording is finished (its summary written), Foxglove stopped."""
        loop = asyncio.get_running_loop()
        if self.recording is not None:
            await self.stop_recording()
        if self.live is not None:
            await loop.run_in_executor(None, self.live.close)
        await loop.run_in_executor(None, self.hub.close)

