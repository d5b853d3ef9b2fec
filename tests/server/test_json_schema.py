"""JSON mode through real sockets: every reply line matches docs/replies.schema.json, and the keys
whose JSON type could depend on the command or the case (job, worst, waypoints, lists, rounded
numbers, config settings) have one type; the greeting comes in JSON to a client that asks at connect."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest
from jsonschema import Draft202012Validator
from support.server import ServerThread

from rvs_server.client import console as rvs_client
from rvs_server.client import replay
from rvs_server.client.session import Session

ROOT = Path(__file__).resolve().parents[2]
VALIDATOR = Draft202012Validator(json.loads((ROOT / "docs" / "replies.schema.json").read_text()))
REPLAYS = sorted((ROOT / "tests" / "replays").glob("*.rvs"))
FINAL = ("OK", "ERROR")
# what a replay expectation says the final line is: text (MODULE STATUS) or JSON ("status":...)
EXPECTED_FINAL = re.compile(r'(RVS|EGP-RVS-[A-Z0-9-]+)(?: |","status":")(OK|ERROR)\b')


def problems(obj: Any) -> list[str]:
    return [f"{'/'.join(map(str, e.absolute_path)) or 'line'}: {e.message}" for e in VALIDATOR.iter_errors(obj)]


def valid(line: str) -> dict[str, Any]:
    """The line as a JSON object, once the schema has passed it."""
    obj = json.loads(line)
    assert not problems(obj), f"{line}\n" + "\n".join(problems(obj))
    return obj


class JsonClient:
    """What a JSON-only GNC does: format json at connect, then only JSON. Every line it reads is
    checked against the schema and kept, so a test can look for the EVENTs that came meanwhile."""

    def __init__(self, server: ServerThread) -> None:
        self.raw = server.client()
        self.lines: list[dict[str, Any]] = []
        self._n = 0
        self.raw.send("format json")
        self.format_ok = self.next()
        self.greeting = self.next()

    def next(self, timeout: float | None = None) -> dict[str, Any]:
        obj = valid(self.raw.line(timeout))
        self.lines.append(obj)
        return obj

    def _send(self, text: str) -> str:
        self._n += 1
        tag = f"j{self._n}"
        self.raw.send(f"@{tag} {text}")
        return tag

    def request(self, text: str, timeout: float = 120) -> dict[str, Any]:
        """The request's final line."""
        tag = self._send(text)
        while True:
            obj = self.next(timeout)
            if obj.get("tag") == tag and obj["status"] in FINAL:
                return obj

    def start(self, text: str) -> tuple[str, int]:
        """Start a job: its tag and id."""
        tag = self._send(text)
        while True:
            obj = self.next()
            if obj.get("tag") == tag:
                assert obj["status"] == "ACK", obj
                return tag, obj["job"]

    def final(self, tag: str, timeout: float = 120) -> dict[str, Any]:
        """The final line of a job started with :meth:`start`."""
        for obj in self.lines:
            if obj.get("tag") == tag and obj["status"] in FINAL:
                return obj
        while True:
            obj = self.next(timeout)
            if obj.get("tag") == tag and obj["status"] in FINAL:
                return obj

    def event(self, kind: str, after: int = 0, timeout: float = 30, **match: Any) -> dict[str, Any]:
        """The first EVENT of ``kind`` (with ``match``ing keys) among the lines read from index
        ``after`` on, reading more as needed."""
        i = after
        while True:
            while i < len(self.lines):
                obj = self.lines[i]
                i += 1
                if obj["status"] == "EVENT" and obj.get("kind") == kind and all(
                        obj.get(k) == v for k, v in match.items()):
                    return obj
            self.next(timeout)

    def close(self) -> None:
        self.raw.close()


@pytest.fixture
def jclient(server: ServerThread) -> Any:
    c = JsonClient(server)
    yield c
    c.close()


# ---------------------------------------------------------------------- the schema itself


GOOD_AND_BAD = [
    pytest.param({"module": "EGP-RVS-STATUS", "status": "OK", "mode": "ready", "job": None},
                 {"module": "EGP-RVS-STATUS", "status": "OK", "mode": "ready", "job": "none"}, id="job-word"),
    pytest.param({"module": "EGP-RVS-CHECK-MOVE", "status": "OK", "worst": "0.850"},
                 {"module": "EGP-RVS-CHECK-MOVE", "status": "OK", "worst": 0.85}, id="worst-number"),
    pytest.param({"module": "RVS", "status": "EVENT", "kind": "waiting", "job": 3, "leg": 1, "file": "nav/a.csv",
                  "waypoints": [[0.0, 0.0, 10.0], [1.0, 0.5, 10.0]]},
                 {"module": "RVS", "status": "EVENT", "kind": "waiting", "job": 3, "leg": 1, "file": "nav/a.csv",
                  "waypoints": [0.0, 0.0, 1.0, 0.5]}, id="waypoints-flat"),
    pytest.param({"module": "EGP-RVS-NAVIGATE", "status": "OK", "job": 3, "waypoints": "nav/a_waypoints.csv"},
                 {"module": "EGP-RVS-NAVIGATE", "status": "OK", "job": 3, "waypoints": [[0.0, 0.0, 1.0]]},
                 id="waypoints-file"),
    pytest.param({"module": "EGP-RVS-STATUS", "status": "OK", "devices": ["ptu:ok", "tof:ok"]},
                 {"module": "EGP-RVS-STATUS", "status": "OK", "devices": "ptu:ok,tof:ok"}, id="list-as-text"),
    pytest.param({"module": "EGP-RVS-STATUS", "status": "OK", "pose": [1.0, 2.0, 90.0]},
                 {"module": "EGP-RVS-STATUS", "status": "OK", "pose": [1.0, 2.0]}, id="pose-short"),
    pytest.param({"module": "EGP-RVS-SLEEP", "status": "ACK", "job": 1},
                 {"module": "EGP-RVS-SLEEP", "status": "ACK", "job": None}, id="ack-without-job"),
    pytest.param({"module": "EGP-RVS-SLEEP", "status": "PROGRESS", "job": 1, "done": 0, "total": 1, "message": ""},
                 {"module": "EGP-RVS-SLEEP", "status": "PROGRESS", "job": 1, "done": 0, "message": ""},
                 id="progress-without-total"),
    pytest.param({"module": "RVS", "status": "ERROR", "code": "E_UNKNOWN", "message": "m"},
                 {"module": "RVS", "status": "ERROR", "message": "m"}, id="error-without-code"),
    pytest.param({"module": "EGP-RVS-VERSION", "status": "OK", "protocol": 1},
                 {"module": "EGP-RVS-VERSION", "status": "OK", "protocol": 1, "protocl": 1}, id="undeclared-key"),
    pytest.param({"module": "EGP-RVS-CONFIG", "status": "OK", "module_name": "ground_align", "settings": {"height": False}},
                 {"module": "EGP-RVS-CONFIG", "status": "OK", "module_name": "ground_align", "height": False},
                 id="setting-as-reply-key"),
]


@pytest.mark.parametrize(("good", "bad"), GOOD_AND_BAD)
def test_the_schema_passes_the_right_type_and_fails_a_mistyped_line(good: dict[str, Any], bad: dict[str, Any]) -> None:
    assert problems(good) == []
    assert problems(bad)


# ---------------------------------------------------------------------- every line of the replays


class RecordingSession(Session):
    """A session that also keeps every line the server sends after the text greeting, including
    those it does not hand on (the JSON greeting)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.received: list[str] = []

    def _route(self, text: str) -> None:
        self.received.append(text)
        super()._route(text)


@pytest.mark.parametrize("script", REPLAYS, ids=lambda p: p.name)
def test_every_line_of_the_replay_suites_matches_the_schema(script: Path, server_factory: Any) -> None:
    steps = [item for item in replay.load(script) if isinstance(item, replay.Step)]
    # format text would take the rest of the script out of JSON
    steps = [s for s in steps if not re.fullmatch(r"(@\S+\s+)?format\s+text", s.request, re.I)]
    srv = server_factory()
    with RecordingSession("127.0.0.1", srv.port) as session:
        session.connect()
        assert session.set_format("json", timeout=30).ok
        assert json.loads(session.greeting or "")["kind"] == "hello"
        for step in steps:
            result = session.request(step.request, timeout=60)
            assert result.final is not None, f"{step.where}: {step.request}: {result.outcome}"
            got = result.final.reply
            m = EXPECTED_FINAL.match(step.expect[-1]) if step.expect else None
            if m:  # the same outcome as the script expects in text
                assert (got.module, got.status) == m.groups(), f"{step.where}: {result.final.text}"
    assert len(session.received) > len(steps)
    for line in session.received:
        valid(line)


# ---------------------------------------------------------------------- one type per key


def test_status_job_is_null_without_a_job_and_an_integer_with_one(server: ServerThread, jclient: JsonClient) -> None:
    status = jclient.request("status")
    assert status["job"] is None and "job_command" not in status and status["recovery"] is None
    runner = JsonClient(server)
    tag, job = runner.start("sleep -seconds 30")
    status = jclient.request("status")
    assert isinstance(job, int) and status["job"] == job
    assert status["job_command"] == "sleep" and re.fullmatch(r"\d+/\d+", status["progress"])
    assert jclient.request("break")["interrupted"] == job
    assert runner.final(tag)["code"] == "E_INTERRUPTED"
    assert jclient.request("break")["interrupted"] is None  # nothing left to interrupt
    status = jclient.request("status")
    assert status["job"] is None and status["recovery"].startswith("recovery/")
    text = server.client()  # the same value is none in text
    assert text.request("status").fields["job"] == "none"
    runner.close()
    text.close()


def test_numbers_carry_the_figures_text_prints(server: ServerThread, jclient: JsonClient) -> None:
    pose = jclient.request("pose -x 1.23456 -y -2.0004 -heading 12.3456")
    assert (pose["x"], pose["y"], pose["heading"]) == (1.235, -2.0, 12.35)
    text = server.client()
    shown = text.request("pose").fields
    assert (shown["x"], shown["y"], shown["heading"]) == ("1.235", "-2.000", "12.35")
    # a plain float: 6 significant digits, as text prints it
    cfg = jclient.request("config -module sleep -set seconds=0.123456789")
    assert cfg["settings"] == {"seconds": 0.123457}
    assert text.request("config -module sleep").fields["seconds"] == "0.123457"
    slept = jclient.request("sleep -seconds 0.01")["slept"]
    assert slept == round(slept, 3) and 0.01 <= slept < 1
    uptime = jclient.request("status")["uptime"]
    assert uptime == round(uptime, 1)
    text.close()


def test_lists_are_arrays_and_config_settings_one_object(server: ServerThread, jclient: JsonClient) -> None:
    status = jclient.request("status")
    assert status["pose"] == [0.0, 0.0, 0.0] and len(status["ptu"]) == 2
    assert status["devices"] and all(re.fullmatch(r"[a-z]+:\S+", d) for d in status["devices"])
    text = server.client()
    assert text.request("status").fields["devices"] == ",".join(status["devices"])
    reset = jclient.request("reset")
    assert reset["checked"] == [f"{d.split(':')[0]}:ok" for d in status["devices"]]
    # a module's settings keep the module's types (ground-align's height is a flag, a reply's a length)
    cfg = jclient.request("config -module ground_align")
    assert cfg["module_name"] == "ground_align" and cfg["settings"]["height"] is False
    cfg = jclient.request("config -module drivers")
    assert cfg["settings"]["ptu"]["backend"] == "sim"
    assert text.request("config -module drivers").fields["ptu_backend"] == "sim"  # text spreads them
    text.close()


def test_check_move_worst_is_a_string_in_both_outcomes(server: ServerThread, jclient: JsonClient) -> None:
    dem = jclient.request("dem-full-tof -range -30,30,-50,-30 -name near", timeout=300)
    assert dem["status"] == "OK" and isinstance(dem["cells"], int) and dem["coverage"] == round(dem["coverage"], 3)
    text = server.client()
    jclient.request("pose -x 1.5 -y 0 -heading 0")  # on ground the scan saw, 1.5 m ahead
    seen = jclient.request("check-move -dx 0.2")
    assert seen["verdict"] in ("ok", "not_traversable") and re.fullmatch(r"\d\.\d{3}", seen["worst"])
    assert text.request("check-move -dx 0.2").fields["worst"] == seen["worst"]
    assert seen["to"] == [1.7, 0.0, 0.0]
    jclient.request("pose -x 100 -y 100")  # far off the map: nothing seen
    unseen = jclient.request("check-move -dx 0.2")
    assert (unseen["verdict"], unseen["worst"]) == ("unknown", "unknown")
    assert isinstance(unseen["worst_x"], float) and isinstance(unseen["unknown_cells"], int)
    text.close()


# ---------------------------------------------------------------------- events


def test_hazard_events_in_json(server: ServerThread, jclient: JsonClient) -> None:
    r = jclient.request("hazard-start -period 0.05 -lookahead 4 -warn-distance 3 -stop-distance 1")
    assert r["status"] == "OK" and r["restarted"] is False
    warning = jclient.event("hazard", timeout=60)  # the rock ahead of the office rover
    assert warning["level"] == "warning" and warning["seen"] == "true" and isinstance(warning["cycle"], int)
    assert warning["distance"] == round(warning["distance"], 2) and 0 < warning["distance"] <= 3
    mark = len(jclient.lines)
    # (a job that lasts until the break: a short one could end before a slow monitor cycle does)
    tag, job = jclient.start("sleep -seconds 60")
    paused = jclient.event("hazard", after=mark, level="paused")
    assert (paused["reason"], paused["job"]) == ("job", job)
    assert jclient.request("break")["interrupted"] == job
    assert jclient.final(tag)["code"] == "E_INTERRUPTED"
    assert jclient.request("continue")["mode"] == "ready"
    mark = len(jclient.lines)
    assert jclient.request("sim fault -device tof -kind unplug")["fault"] == "unplug"
    failed = jclient.event("hazard", after=mark, level="error")
    assert (failed["code"], failed["device"]) == ("E_DEVICE", "tof")


def test_track_events_in_json(server_factory: Any) -> None:
    srv = server_factory(["server.scene=quarry"])
    world = srv.app.world
    c = JsonClient(srv)
    world.set_target_visible(False)
    assert c.request("track3d-detect -range -30,30,-15,0")["found"] is False
    assert c.request("track3d-start")["target"] is None
    assert c.request("track3d-stop")["stopped"] is True
    world.set_target_visible(True)
    world.set_target_time(7.0)  # standing in view, about 4 m ahead
    found = c.request("track3d-detect -range -30,30,-15,0")
    assert found["found"] is True and isinstance(found["candidates"], int)
    start = c.request("track3d-start")
    assert start["target"] == [found["x"], found["y"], found["z"]]
    mark = len(c.lines)
    fix = c.event("track", after=mark)
    assert {"x", "y", "z", "vx", "vy", "rate", "time"} <= set(fix) and all(
        isinstance(fix[k], float) for k in ("x", "y", "z", "vx", "vy", "rate", "time"))
    world.set_target_visible(False)
    lost = c.event("track", after=mark, lost=True)
    assert isinstance(lost["last_x"], float)
    stop = c.request("track3d-stop")
    assert stop["stopped"] is True and stop["losses"] >= 1
    c.close()


def test_the_waiting_event_gives_waypoints_as_rows(server_factory: Any) -> None:
    # a narrow scan per leg (the leg's DEM is all this test needs) keeps it to a few seconds
    srv = server_factory(["server.scene=office", "navigate.range=-110,30,-55,-20", "navigate.overlap=0.05",
                          "navigate.border=0.3"])
    c, gnc = JsonClient(srv), srv.client()
    tag, job = c.start("navigate -goal 1.5,-1.2 -loop scan -scan-plan circle -name rows")
    event = c.event("waiting", timeout=300)
    assert (event["job"], event["leg"]) == (job, 1) and event["file"].endswith("_leg1_waypoints.csv")
    rows = event["waypoints"]
    assert len(rows) >= 2 and all(len(row) == 3 for row in rows)
    assert rows[0][:2] == [0.0, 0.0]  # from where the rover stands
    assert all(row[2] == round(row[2], 2) and -180 < row[2] <= 180 for row in rows)
    while True:  # text runs the same records together
        line = gnc.reply(timeout=60)
        if line.status == "EVENT" and line.fields.get("kind") == "waiting":
            break
    assert [float(v) for v in line.fields["waypoints"].split(",")] == [v for row in rows for v in row]
    assert c.request("break")["interrupted"] == job
    assert c.final(tag)["code"] == "E_INTERRUPTED"
    c.close()
    gnc.close()


# ---------------------------------------------------------------------- the greeting


def test_format_json_at_connect_time_sends_the_greeting_again_in_json(server: ServerThread) -> None:
    c = server.client()
    assert c.greeting.startswith("RVS EVENT kind=hello ")
    assert c.request("events off").fields["events"] == "off"  # the greeting is a reply, not an event
    c.send("format json\nstatus")  # in one write: the greeting still comes right after the OK
    got = [valid(c.line()) for _ in range(3)]
    assert got[0] == {"module": "EGP-RVS-FORMAT", "status": "OK", "format": "json"}
    assert got[1] == {"module": "RVS", "status": "EVENT", "kind": "hello", "protocol": 1,
                      "server": "rvs/0.1.0", "mode": "ready", "console": "off"}
    assert (got[2]["module"], got[2]["job"]) == ("EGP-RVS-STATUS", None)
    # once the connection has started a job, format json only switches
    c.send("format text")
    assert c.reply().fields["format"] == "text"
    assert c.request("sleep -seconds 0").status == "OK"
    c.send("format json\nversion")
    assert [valid(c.line())["module"] for _ in range(2)] == ["EGP-RVS-FORMAT", "EGP-RVS-VERSION"]
    c.close()


def test_rvs_client_format_json_prints_a_json_greeting(server: ServerThread, capsys: pytest.CaptureFixture[str]) -> None:
    rc = rvs_client.main(["--port", str(server.port), "--format", "json", "-v", "-c", "version"])
    got = [valid(line) for line in capsys.readouterr().out.splitlines()]
    assert rc == 0
    assert [(o["module"], o["status"]) for o in got] == [
        ("EGP-RVS-FORMAT", "OK"), ("RVS", "EVENT"), ("EGP-RVS-VERSION", "OK")]
    assert (got[1]["kind"], got[1]["protocol"]) == ("hello", 1)
    # --json is the same switch; without -v the greeting is not shown, as in text
    rc = rvs_client.main(["--port", str(server.port), "--json", "-c", "version"])
    assert rc == 0
    assert [valid(line)["module"] for line in capsys.readouterr().out.splitlines()] == ["EGP-RVS-VERSION"]
