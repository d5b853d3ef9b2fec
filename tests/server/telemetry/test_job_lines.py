"""A job's lines reach the record whoever is still there to read them: the final line of a job
whose client left before it ended is in a recording (/rvs/wire, /rvs/log, /rvs/job) and in the
history a console page opened later is shown; /rvs/job holds the lines of jobs only, not the
replies that name a job (``status -job N``)."""

from __future__ import annotations

import asyncio
import json
import socket
import struct
from typing import Any

import aiohttp
from support.mcap import decoded
from support.server import wait_for


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def history_of_a_new_page(port: int) -> list[dict[str, Any]]:
    """The lines a console page opened now is shown (its first message)."""
    async def go() -> list[dict[str, Any]]:
        async with aiohttp.ClientSession() as http, http.ws_connect(f"ws://127.0.0.1:{port}/ws") as ws:
            msg = json.loads((await ws.receive(timeout=30)).data)
            assert msg["type"] == "history", msg
            return msg["lines"]

    return asyncio.run(go())


def test_the_final_line_of_a_job_whose_client_left_is_recorded_and_shown_to_later_pages(server_factory: Any) -> None:
    web_port = free_port()
    srv = server_factory([f"server.web_port={web_port}"])
    c = srv.client()
    assert c.request("record -start -name orphan").status == "OK"
    with srv.app.device_lock:  # the job waits for it: its client is gone before it can end
        gone = srv.client()
        gone.send("grab-tof -output orphan -type amplitude")
        ack = gone.reply()
        assert ack.status == "ACK", ack
        job = int(ack.fields["job"])
        conn = max(conn.id for conn in srv.app.connections)
        # gone for good: a reset, as a client killed or a network lost makes, not a half-close
        gone.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        gone.close()
        assert wait_for(lambda: conn not in {k.id for k in srv.app.connections}, 30.0)
    assert wait_for(lambda: c.request(f"status -job {job}").fields.get("job_state") != "running", 120.0)
    st = c.request(f"status -job {job}")
    assert st.fields["job_state"] == "ok" and st.fields["final_status"] == "OK", st
    stop = c.request("record -stop")
    assert stop.status == "OK", stop

    messages = decoded(srv.data / "recordings" / "orphan.mcap")
    wire = [msg for topic, _, msg in messages if topic == "/rvs/wire" and msg["conn"] == conn]
    replies = [w["line"].split()[1] for w in wire if w["dir"] == "reply"]
    assert replies[0] == "ACK" and replies[-1] == "OK" and set(replies[1:-1]) <= {"PROGRESS"}, wire
    assert f"job={job}" in wire[-1]["line"] and "EGP-RVS-GRAB-TOF" in wire[-1]["line"]
    logged = [msg.message for topic, _, msg in messages if topic == "/rvs/log"]
    assert any(line.startswith("EGP-RVS-GRAB-TOF OK") and f"job={job}" in line for line in logged), logged
    jobs = [msg for topic, _, msg in messages if topic == "/rvs/job"]
    own = [(j["command"], j["status"]) for j in jobs if j["job"] == job]
    assert own[0] == ("EGP-RVS-GRAB-TOF", "ACK") and own[-1] == ("EGP-RVS-GRAB-TOF", "OK"), jobs
    assert {status for _, status in own[1:-1]} <= {"PROGRESS"}, jobs
    # status -job N names job N but is no line of it
    assert not [j for j in jobs if j["command"] == "EGP-RVS-STATUS"], jobs

    lines = [m["reply"] for m in history_of_a_new_page(web_port) if m["reply"].get("job") == job]
    assert [r["status"] for r in lines] == ["ACK", "OK"], lines


def test_a_page_reloaded_during_a_job_is_shown_its_final_line_by_the_next_page(server_factory: Any) -> None:
    web_port = free_port()
    srv = server_factory([f"server.web_port={web_port}"])

    async def start_and_leave() -> int:
        async with aiohttp.ClientSession() as http, http.ws_connect(f"ws://127.0.0.1:{web_port}/ws") as ws:
            await ws.send_str(json.dumps({"line": "@reload sleep -seconds 0.2"}))
            while True:
                msg = json.loads((await ws.receive(timeout=30)).data)
                if msg["type"] == "reply" and msg["reply"]["status"] == "ACK":
                    return int(msg["reply"]["job"])

    with srv.app.device_lock:
        job = asyncio.run(start_and_leave())
        assert wait_for(lambda: not srv.app.console.pages, 30.0)
    with srv.client() as c:
        assert wait_for(lambda: c.request(f"status -job {job}").fields.get("job_state") == "ok", 60.0)
    lines = [m["reply"] for m in history_of_a_new_page(web_port) if m["reply"].get("job") == job]
    assert [r["status"] for r in lines] == ["ACK", "OK"], lines


def test_rvs_job_holds_the_lines_of_jobs_not_the_replies_that_name_one(server: Any) -> None:
    c = server.client()
    assert c.request("record -start -name named").status == "OK"
    assert c.request("sleep -seconds 0.01").status == "OK"
    st = c.request("status -job 1")
    assert st.status == "OK" and st.fields["job"] == "1", st
    assert c.request("record -stop").status == "OK"
    jobs = [msg for topic, _, msg in decoded(server.data / "recordings" / "named.mcap") if topic == "/rvs/job"]
    assert [(j["job"], j["command"], j["status"]) for j in jobs] == [(1, "EGP-RVS-SLEEP", "ACK"),
                                                                     (1, "EGP-RVS-SLEEP", "OK")], jobs
