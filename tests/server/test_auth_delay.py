"""Wrong tokens slow down further guesses on the same connection only: the TCP server and the web
console's WebSocket, through real sockets, with the server's own log file."""

from __future__ import annotations

import asyncio
import json
import select
import socket
import time
from typing import Any

import aiohttp
from support.server import LineClient, wait_for

TOKEN = "s3cret"
DELAY, CAP = 0.4, 1.0  # server.auth_delay and server.auth_delay_max: waits 0, 0.4, 0.8, 1.0, 1.0...


def _server(server_factory: Any, *overrides: str) -> Any:
    return server_factory([f"server.token={TOKEN}", f"server.auth_delay={DELAY}", f"server.auth_delay_max={CAP}",
                           *overrides])


def _log(srv: Any, event: str) -> list[dict[str, Any]]:
    lines = [json.loads(line) for line in (srv.data / "rvs.log").read_text().splitlines() if line.strip()]
    return [entry for entry in lines if entry.get("event") == event]


def _timed(client: LineClient, line: str) -> tuple[Any, float]:
    start = time.monotonic()
    reply = client.request(line)
    return reply, time.monotonic() - start


def _unanswered(client: LineClient) -> bool:
    return not client.buf and not select.select([client.sock], [], [], 0)[0]


def test_each_wrong_token_delays_the_next_auth_on_that_connection_only(server_factory: Any) -> None:
    srv = _server(server_factory)
    other = srv.client()
    assert other.request(f"auth -token {TOKEN}").status == "OK"
    guesser = srv.client()
    first = guesser.request("auth -token wrong1")
    assert first.fields["code"] == "E_AUTH" and "answered after 0.4 s" in first.fields["message"]
    second, waited = _timed(guesser, "auth -token wrong2")
    assert second.fields["code"] == "E_AUTH" and "answered after 0.8 s" in second.fields["message"]
    assert waited >= DELAY

    start = time.monotonic()
    guesser.send("auth -token wrong3")
    # the guesser waits, the other connection does not: its status comes back while the third
    # auth is still unanswered
    status = other.request("status")
    assert status.status == "OK" and _unanswered(guesser)
    third = guesser.reply()
    assert time.monotonic() - start >= 2 * DELAY
    assert third.fields["code"] == "E_AUTH" and "answered after 1 s" in third.fields["message"]  # the cap

    right, waited = _timed(guesser, f"auth -token {TOKEN}")
    assert right.status == "OK" and right.fields["authenticated"] == "true" and waited >= CAP
    assert guesser.request("status").status == "OK"

    delayed = _log(srv, "auth_delayed")
    assert [(d["conn"], d["seconds"], d["failures"]) for d in delayed] == [
        (delayed[0]["conn"], DELAY, 1), (delayed[0]["conn"], 2 * DELAY, 2), (delayed[0]["conn"], CAP, 3)]
    failed = _log(srv, "auth_failed")
    assert [(f["failures"], f["next_wait"]) for f in failed] == [(1, DELAY), (2, 2 * DELAY), (3, CAP)]


def test_a_new_connection_starts_without_a_wait(server_factory: Any) -> None:
    srv = _server(server_factory)
    guesser = srv.client()
    for _ in range(3):
        assert guesser.request("auth -token wrong").fields["code"] == "E_AUTH"
    guesser.close()
    fresh = srv.client()
    r = fresh.request("auth -token wrong")
    assert r.fields["code"] == "E_AUTH" and "answered after 0.4 s" in r.fields["message"]  # its first failure
    assert fresh.request(f"auth -token {TOKEN}").status == "OK"
    assert [d["failures"] for d in _log(srv, "auth_delayed")] == [1, 2, 1]  # the guesser's two, fresh's one


def test_the_console_page_waits_the_same_while_tcp_clients_are_served(server_factory: Any) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    srv = _server(server_factory, f"server.web_port={port}")
    other = srv.client()
    assert other.request(f"auth -token {TOKEN}").status == "OK"

    async def final(ws: aiohttp.ClientWebSocketResponse, tag: str) -> dict[str, Any]:
        while True:
            data = json.loads((await asyncio.wait_for(ws.receive(), 30)).data)
            reply = data.get("reply") or {}
            if data["type"] == "reply" and reply.get("tag") == tag and reply["status"] in ("OK", "ERROR"):
                return reply

    async def page() -> list[tuple[dict[str, Any], float]]:
        out = []
        async with aiohttp.ClientSession() as http, http.ws_connect(f"ws://127.0.0.1:{port}/ws") as ws:
            for i, token in enumerate(("wrong", "wrong", "wrong", TOKEN)):
                start = time.monotonic()
                await ws.send_str(json.dumps({"line": f"@a{i} auth -token {token}"}))
                answer = asyncio.create_task(final(ws, f"a{i}"))
                if i == 2:  # a TCP client is served while the page waits
                    status = await asyncio.to_thread(other.request, "status")
                    assert status.status == "OK" and not answer.done()
                out.append((await answer, time.monotonic() - start))
        return out

    replies = asyncio.run(page())
    assert [r["code"] for r, _ in replies[:3]] == ["E_AUTH"] * 3
    assert "answered after 0.8 s" in replies[1][0]["message"]
    assert replies[1][1] >= DELAY and replies[2][1] >= 2 * DELAY and replies[3][1] >= CAP
    assert replies[3][0]["status"] == "OK"
    assert wait_for(lambda: len(_log(srv, "auth_delayed")) == 3)
    assert all(d.get("web") for d in _log(srv, "auth_delayed"))
