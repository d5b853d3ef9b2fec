"""Wrong tokens slow down further guesses from the same client address, however often it
reconnects, and nobody else: the TCP server and the web console's WebSocket, through real
sockets, with the server's own log file; and the table of addresses, bounded and forgetful."""

from __future__ import annotations

import asyncio
import json
import select
import socket
import time
from typing import Any

import aiohttp
from support.server import LineClient, wait_for

from rvs_server.auth_failures import AuthFailures

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


def test_each_wrong_token_delays_the_next_auth_and_only_the_guessers_lines(server_factory: Any) -> None:
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


def test_a_reconnecting_guesser_waits_what_its_address_has_earned_and_others_are_served(server_factory: Any) -> None:
    srv = _server(server_factory)
    other = srv.client()
    assert other.request(f"auth -token {TOKEN}").status == "OK"
    first = srv.client()
    for _ in range(2):  # waits 0, then 0.4: the address has earned 0.8 s
        assert first.request("auth -token wrong").fields["code"] == "E_AUTH"
    first.close()
    second = srv.client()  # a new connection from 127.0.0.1: no fresh start
    start = time.monotonic()
    second.send("auth -token wrong")
    status = other.request("status")  # meanwhile another connection is answered at once
    assert status.status == "OK" and _unanswered(second)
    r = second.reply()
    assert time.monotonic() - start >= 2 * DELAY
    assert r.fields["code"] == "E_AUTH" and "from 127.0.0.1 is answered after 1 s" in r.fields["message"]
    # a right token from the address clears it: the next connection's wrong token costs no wait
    assert second.request(f"auth -token {TOKEN}").status == "OK"
    third = srv.client()
    assert "answered after 0.4 s" in third.request("auth -token wrong").fields["message"]
    delayed = _log(srv, "auth_delayed")
    assert [(d["failures"], d["seconds"], d["address"]) for d in delayed] == [
        (1, DELAY, "127.0.0.1"), (2, 2 * DELAY, "127.0.0.1"), (3, CAP, "127.0.0.1")]
    assert len({d["conn"] for d in delayed}) == 2  # the first connection's, then the second's


def test_parallel_connections_from_one_address_guess_one_at_a_time(server_factory: Any) -> None:
    srv = _server(server_factory)
    seed = srv.client()
    assert seed.request("auth -token wrong").fields["code"] == "E_AUTH"  # the address has a wrong token
    guessers = [srv.client() for _ in range(3)]
    start = time.monotonic()
    for g in guessers:
        g.send("auth -token wrong")
    for g in guessers:
        assert g.reply().fields["code"] == "E_AUTH"
    # one after another: 0.4 + 0.8 + 1.0 s, not the 0.4 s three side by side would take
    assert time.monotonic() - start >= DELAY + 2 * DELAY + CAP
    assert sorted(d["failures"] for d in _log(srv, "auth_delayed")) == [1, 2, 3]


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


def test_the_address_table_forgets_a_quiet_address_and_keeps_a_bounded_number() -> None:
    now = [0.0]
    table = AuthFailures(clock=lambda: now[0])
    assert table.failed("10.0.0.1", size=2) == 1
    now[0] = 5.0
    assert table.failed("10.0.0.1", size=2) == 2
    assert table.of("10.0.0.1", forget_after=60.0).failures == 2
    now[0] = 64.0  # 59 s after its last wrong token: still remembered
    assert table.of("10.0.0.1", forget_after=60.0) is not None
    now[0] = 66.0  # past the quiet period: forgotten
    assert table.of("10.0.0.1", forget_after=60.0) is None and len(table) == 0
    for i, address in enumerate(("10.0.0.1", "10.0.0.2", "10.0.0.3")):
        now[0] = 100.0 + i
        table.failed(address, size=2)
    # full: the address quiet longest went first
    assert table.of("10.0.0.1", 60.0) is None and table.of("10.0.0.3", 60.0).failures == 1 and len(table) == 2
    table.clear("10.0.0.3")
    assert table.of("10.0.0.3", 60.0) is None
