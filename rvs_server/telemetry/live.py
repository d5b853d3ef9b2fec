"""The live Foxglove server (foxglove-sdk's WebSocket server, in threads of its own inside the
telemetry process).

It is read-only whoever connects: it advertises no capability that lets a client publish, call
a service or set a parameter, so what the console without its token cannot change, Foxglove
cannot either; commands go through the TCP port or the unlocked console. Like the console it
listens on loopback unless the server has a token or ``server.web_public`` says otherwise.

The SDK speaks the foxglove.websocket.v1 protocol under the subprotocol name
``foxglove.sdk.v1`` (the Foxglove app and its bridge use that name; the messages are the same)
and accepts no other; clients that offer the old name (``@foxglove/ws-protocol``, Lichtblick)
come in through :mod:`.subprotocol`'s relay, which holds the Foxglove port.
"""

from __future__ import annotations

from collections.abc import Callable

import foxglove
from foxglove.websocket import ChannelView, Client, ServerListener

from .outlet import Outlet
from .subprotocol import SubprotocolRelay


class _Listener(ServerListener):
    """Runs in the SDK's threads: passes each subscription on (a late subscriber is sent what is
    latched on the topic by whoever owns the latched copies) and returns."""

    def __init__(self, on_subscribe: Callable[[str], None]) -> None:
        self.on_subscribe_topic = on_subscribe

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self.on_subscribe_topic(channel.topic)


class LiveOutlet(Outlet):
    """The Foxglove server on ``host:port``; raises RuntimeError if it cannot bind. A channel is
    advertised once its topic has something to say (its first message, or the hub's offer when
    nobody listens yet), so a client lists no channel that stays empty (a hazard camera not
    fitted, a map layer no DEM makes).
    ``on_subscribe(topic)`` is called in the SDK's threads when a client subscribes."""

    def __init__(self, host: str, port: int, name: str, on_subscribe: Callable[[str], None]) -> None:
        super().__init__(live=True)
        self.relay = SubprotocolRelay(host, port)  # first: a port taken costs nothing else
        try:
            self.server = foxglove.start_server(name=name, host="127.0.0.1", port=0, context=self.context,
                                                server_listener=_Listener(on_subscribe), capabilities=[])
            self.relay.start(self.server.port)
        except BaseException:
            self.relay.close()
            raise
        self.url = f"ws://{f'[{host}]' if ':' in host else host}:{self.relay.port}"

    def close(self) -> None:
        self.relay.close()
        self.server.stop()
