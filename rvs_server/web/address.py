"""Where the web console listens and what ``status`` says of it: what the server asks of the
console whether or not one runs, apart from the console itself, so that a server without a
console (``web_port`` 0, as every test server and replay has) never loads aiohttp (a third of a
second of its start)."""

from __future__ import annotations

import ipaddress
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ..app import App


def is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


def console_host(host: str, token: str, public: bool) -> str:
    """Where the console listens: the server's host, but loopback without a token unless the
    operator asked for a public console (the page can drive the rover)."""
    if token or public or is_loopback(host):
        return host
    return "127.0.0.1"


def console_fields(app: App) -> dict[str, Any]:
    """What status says of the console: where it is, or why there is none."""
    if app.console is not None:
        return {"console": "on", "console_url": app.console.url}
    return {"console": "off", "console_reason": app.console_off or "not started"}
