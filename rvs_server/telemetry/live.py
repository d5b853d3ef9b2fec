"""The live Foxglove server (foxglove-sdk's WebSocket server, in its own threads).

It is read-only whoever connects: it advertises no capability that lets a client publish, call
a service or set a parameter, so what the console without its token cannot change, Foxglove
cannot either; commands go through the TCP port or the unlocked console. Like the console it
listens on loopback unless the server has a token or ``server.web_public`` says otherwise.

The SDK speaks the foxglove.websocket.v1 protocol under the subprotocol name
``foxglove.sdk.v1`` (the Foxglove app and its bridge use that name; the messages are the same).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import foxglove
from foxglove.websocket import ChannelView, Client, ServerListener

from .outlet import Outlet

if TYPE_CHECKING:
    from .hub import Telemetry

SUBPROTOCOL = "foxglove.sdk.v1"


class _Listener(ServerListener):
    """A client that subscribes gets what is latched on the topic (a map made before it came)."""

    def __init__(self, hub: Telemetry, outlet: Outlet) -> None:
        self.hub = hub
        self.outlet = outlet

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self.hub.resend(self.outlet, channel.topic)


class LiveOutlet(Outlet):
    """The Foxglove server on ``host:port``; raises OSError-like RuntimeError if it cannot bind."""

    def __init__(self, hub: Telemetry, host: str, port: int, name: str) -> None:
        super().__init__(live=True)
        self.declare()
        self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context,
                                            server_listener=_Listener(hub, self), capabilities=[])
        self.url = f"ws://{f'[{host}]' if ':' in host else host}:{self.server.port}"
        self._hub = hub
        hub.attach(self)

    def close(self) -> None:
        self._hub.detach(self).wait(5.0)
        self.server.stop()
