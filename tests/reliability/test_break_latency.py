"""break answers at once, and the job it caught stops soon after, in a consistent state.

``break`` signals the job and replies; the job's own ERROR follows once it has stopped. Both are
sent on the job's own connection, whose lines the server writes in the order it makes them, so
the order is what these tests assert (a server whose break waits for the job answers after the
job's ERROR). The per-kind order check over every job kind is in test_break_continue.py; these
add what each device leaves behind, quit, and one generous bound where the old wait was long
(a simulated camera renders the highest resolution for seconds). Figures, not assertions, are in
docs/RELIABILITY.md (tools/bench/break_latency.py).
"""

from __future__ import annotations

import time

import pytest
from support.server import LineClient

from rvs_server.protocol import Reply

SLOW_PTU = ["drivers.ptu.time_scale=1", "drivers.ptu.speed=200"]  # a 150-degree move of seconds


def start(c: LineClient, line: str, mark: str) -> str:
    """Send ``@job line`` and return its id once a PROGRESS line's message holds ``mark``."""
    c.send(f"@job {line}")
    job = ""
    while True:
        r = c.reply()
        if r.tag != "job":
            continue
        if r.status == "ACK":
            job = r.fields["job"]
        elif r.status == "PROGRESS" and mark in r.fields.get("message", ""):
            return job
        elif r.status in ("OK", "ERROR"):
            pytest.fail(f"{line} ended before '{mark}': {r}")


def finals_in_order(c: LineClient, tags: tuple[str, ...]) -> list[tuple[Reply, float]]:
    """The final lines of ``tags`` in the order they came, with their arrival times."""
    out: list[tuple[Reply, float]] = []
    while len(out) < len(tags):
        r = c.reply()
        if r.tag in tags and r.status in ("OK", "ERROR"):
            out.append((r, time.monotonic()))
    return out


def test_break_answers_while_the_cameras_render_and_the_grab_stops(server_factory) -> None:
    srv = server_factory()
    c, other = srv.client(), srv.client()
    job = start(c, "grab-stereo -output brk -resolution highest", "grabbing")
    t0 = time.monotonic()
    c.send("@brk break")
    (brk, t_brk), (final, _) = finals_in_order(c, ("brk", "job"))
    assert (brk.tag, brk.status, brk.fields["interrupted"]) == ("brk", "OK", job), brk
    # generous: the old break waited for the render, seconds at this resolution
    assert t_brk - t0 < 1.0, f"break answered after {t_brk - t0:.2f} s"
    assert (final.tag, final.status, final.fields["code"]) == ("job", "ERROR", "E_INTERRUPTED"), final
    assert other.request("status").fields["mode"] == "break"
    assert c.request("continue").fields["mode"] == "ready"
    r = c.request("grab-stereo -output again -resolution low")  # the cameras grab again
    assert r.status == "OK", r
    assert srv.app.devices.get("stereo").status()["last_error"] is None


def test_break_leaves_the_ptu_stopped_where_it_is_and_its_position_known(server_factory) -> None:
    srv = server_factory(SLOW_PTU)
    c = srv.client()
    job = start(c, "move-ptu -pan 150 -tilt -30", "moving")
    time.sleep(0.3)  # under way
    c.send("@brk break")
    (brk, _), (final, _) = finals_in_order(c, ("brk", "job"))
    assert brk.tag == "brk" and brk.fields["interrupted"] == job, brk
    assert final.fields["code"] == "E_INTERRUPTED", final
    emulator = srv.app.devices.get("ptu").emulator
    # continue checks the PTU: it reads the halted move's last reply, then where the axes stood
    assert c.request("continue").fields["mode"] == "ready"
    pan, tilt = (float(v) for v in c.request("status").fields["ptu"].split(","))
    time.sleep(0.2)  # a unit still moving would be elsewhere by now
    true_pan, true_tilt = emulator.position_deg()
    assert pan == pytest.approx(true_pan, abs=0.01) and tilt == pytest.approx(true_tilt, abs=0.01)
    assert 0.5 < pan < 149  # stopped short of its target, past its start
    r = c.request("move-ptu -pan 10 -tilt -5")  # and it moves again from there
    assert r.status == "OK" and float(r.fields["pan"]) == pytest.approx(10, abs=0.1), r


def test_quit_answers_before_the_job_it_stops_ends(server_factory) -> None:
    srv = server_factory(SLOW_PTU)
    c = srv.client()
    job = start(c, "move-ptu -pan -150 -tilt 20", "moving")
    c.send("@q quit")
    (q, _), (final, _) = finals_in_order(c, ("q", "job"))
    assert (q.tag, q.status, q.fields["interrupted"]) == ("q", "OK", job), q
    assert final.fields["code"] == "E_INTERRUPTED", final
    with pytest.raises(ConnectionError):
        while True:
            c.line(timeout=10)
    srv.thread.join(20)
    assert not srv.thread.is_alive() and srv.exit_code == 0


def test_break_after_the_jobs_last_step_says_nothing_was_interrupted(server_factory) -> None:
    """A job whose outcome was settled when the break came ends as it would have (OK), and the
    break, answering before that OK, already says interrupted=none."""
    srv = server_factory()
    c = srv.client()
    for _ in range(20):
        c.send("@job sleep -seconds 0\n@brk break")
        got = {r.tag: r for r, _ in finals_in_order(c, ("job", "brk"))}
        job, brk = got["job"], got["brk"]
        assert (job.status == "OK") == (brk.fields["interrupted"] == "none"), (job, brk)
        if job.status == "ERROR":
            assert job.fields["code"] == "E_INTERRUPTED" and brk.fields["interrupted"] == job.fields["job"]
        assert c.request("continue").status == "OK"
