"""Modes follow the table in docs/PROTOCOL.md exactly: random command sequences through a real TCP
socket, every mode event checked against a model of that table (hypothesis picks the sequences)."""

from __future__ import annotations

from dataclasses import dataclass

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.server import LineClient

BLOCKING = ("standby", "break", "fault")


@dataclass
class ModeTable:
    """docs/PROTOCOL.md's table as a model: what a request does to the mode, and which mode
    events every connection sees because of it."""

    base: str = "ready"

    def step(self, name: str) -> tuple[list[str], str]:
        """(mode events expected, final status of the request) for one step."""
        if name in ("sleep", "move-ptu"):  # a plain job and a hardware job
            if self.base in BLOCKING:
                return [], "ERROR"
            return ["sleep" if name == "sleep" else "busy", self.base], "OK"
        if name == "sleep+break":  # break while a sleep runs
            events = [] if self.base in BLOCKING else ["sleep"]
            if self.base != "break":
                events.append("break")
            self.base = "break"
            return events, "OK"
        if name == "break":
            events = [] if self.base == "break" else ["break"]
            self.base = "break"
            return events, "OK"
        if name in ("continue", "reset", "reinit"):
            self.base = "ready"
            return ["busy", "ready"], "OK"
        if name == "standby":
            events = [] if self.base == "standby" else ["standby"]
            self.base = "standby"
            return events, "OK"
        if name == "status":
            return [], "OK"
        raise AssertionError(name)


REQUESTS = {
    "sleep": "sleep -seconds 0.01",
    "move-ptu": "move-ptu -pan 5 -tilt -5",
    "break": "break",
    "continue": "continue",
    "reset": "reset",
    "reinit": "reinit -device ptu",
    "standby": "standby",
    "status": "status",
}


def mode_events(watcher: LineClient) -> list[str]:
    return [r.fields["mode"] for r in watcher.lines_before_status()
            if r.status == "EVENT" and r.fields.get("kind") == "mode"]


def run_step(c: LineClient, name: str) -> str:
    if name == "sleep+break":
        c.send("sleep -seconds 30")
        first = c.reply()
        c.send("break")
        finals = {}  # the break's answer and the sleep's end come in either order
        want = {"EGP-RVS-BREAK"} | ({"EGP-RVS-SLEEP"} if first.status == "ACK" else set())
        while set(finals) != want:
            r = c.reply()
            if r.status in ("OK", "ERROR"):
                finals[r.module] = r
        if first.status == "ACK":
            assert finals["EGP-RVS-SLEEP"].fields["code"] == "E_INTERRUPTED"
        return finals["EGP-RVS-BREAK"].status
    r = c.request(REQUESTS[name], timeout=60)
    if r.status == "ERROR":
        assert r.fields["code"] == "E_STATE", r
    return r.status


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.sampled_from([*REQUESTS, "sleep+break"]), min_size=1, max_size=10))
def test_every_mode_event_follows_the_table(server, steps: list[str]) -> None:
    c, watcher = server.client(), server.client()
    try:
        assert c.request("events off").status == "OK"  # its own lines only; the watcher sees events
        assert c.request("continue").fields["mode"] == "ready"  # each example starts ready
        mode_events(watcher)
        model = ModeTable()
        for name in steps:
            want_events, want_status = model.step(name)
            status = run_step(c, name)
            assert (name, status) == (name, want_status)
            assert (name, mode_events(watcher)) == (name, want_events)
            assert c.request("status").fields["mode"] == model.base
    finally:
        c.close()
        watcher.close()
