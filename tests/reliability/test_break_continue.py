"""break and continue during every job kind.

The test is parametrised over the job commands of the command table, which is what ``help``
lists (``help CMD`` says ``kind=job``), so a job kind that lands later is covered at once: RECIPES
says how to start each one so that break finds it running. Without a recipe a new job is started
bare; if that is refused the test says which recipe to add.

For each: the job ends ``E_INTERRUPTED`` before its last step (its last PROGRESS line is short of
its total: a job stops at its next cancel check, it does not run on to the end), and break's OK
comes before that ERROR (the break is sent on the job's own connection, whose lines the server
writes in order: break answers without waiting for the job to stop). How long that
takes is recorded, not asserted: the spec's 1.0 s is a figure of an idle machine (RELIABILITY.md:
1 ms to 0.23 s), and a loaded one takes longer over the same steps.
``continue`` while it runs is ``E_BUSY``; the break's
recovery set is complete (manifest.yaml with the job, its parameters, the pose and the PTU
position) and loads back (``yaml.safe_load`` gives the request's values; ``recover -set`` restores
the pose); ``continue`` returns to ready and the same kind of job runs again.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import pytest
import yaml
from support.reliability_figures import record
from support.server import LineClient

from rvs_server.protocol import Reply
from rvs_server.table import COMMANDS

BREAK_WITHIN = 1.0  # seconds from the break request to the job's ERROR line: an idle machine's figure
POSE = ("pose -x 1.25 -y -0.5 -heading 15", {"x": 1.25, "y": -0.5, "heading": 15.0})
DEM_RANGE = "-60,60,-50,-30"


@dataclass
class Recipe:
    """How to catch one job kind running.

    ``wait_for``: break once a PROGRESS line of the job contains it (the job is mid-work then);
    "" breaks 0.2 s after the ACK; None sends the job and the break in one TCP segment, for jobs
    that end in milliseconds (the break is dispatched while the job's thread has barely started)."""

    start: str
    overrides: list[str] = field(default_factory=list)
    setup: list[str] = field(default_factory=list)
    wait_for: str | None = None
    params: dict[str, Any] = field(default_factory=dict)  # must be in the manifest's job parameters
    again: str | None = None  # the same kind of job after continue (default: start)


SLOW_PTU = ["drivers.ptu.time_scale=1", "drivers.ptu.speed=200"]
SLOW_TOF = ["drivers.tof.time_scale=1", "drivers.tof.integration=255"]  # ~0.1 s per frame

RECIPES: dict[str, Recipe] = {
    "sleep": Recipe("sleep -seconds 30", wait_for="", params={"seconds": 30.0}, again="sleep -seconds 0"),
    "move-ptu": Recipe("move-ptu -pan 150 -tilt -30", SLOW_PTU, wait_for="moving", params={"pan": 150.0, "tilt": -30.0},
                       again="move-ptu -tilt 0"),
    "grab-tof": Recipe("grab-tof -output brk -type z -integrate 100", SLOW_TOF, wait_for="grabbing",
                       params={"output": "brk", "type": "z", "integrate": 100}, again="grab-tof -output again -integrate 1"),
    # The simulated cameras render a pair in one piece (about 0.3 s at low resolution, 2 s at the
    # highest): low resolution keeps the render inside the 1 s budget.
    "grab-stereo": Recipe("grab-stereo -output brk -resolution low", params={"output": "brk", "resolution": "low"},
                          again="grab-stereo -output again -resolution low"),
    "dem-full-tof": Recipe(f"dem-full-tof -range {DEM_RANGE} -name brk", ["drivers.ptu.time_scale=0.5"],
                           wait_for="view 2/", params={"range": [-60.0, 60.0, -50.0, -30.0], "name": "brk"},
                           again="dem-full-tof -range -10,10,-45,-35 -name again"),
    "dem-update-tof": Recipe(f"dem-update-tof -range {DEM_RANGE} -name brk", ["drivers.ptu.time_scale=0.5"],
                             setup=["dem-full-tof -range -10,10,-45,-35 -name base"], wait_for="view 2/",
                             params={"range": [-60.0, 60.0, -50.0, -30.0], "name": "brk"},
                             again="dem-update-tof -range -10,10,-45,-35 -name again"),
    "navigate": Recipe("navigate -goal 1.5,0 -loop scan -scan-plan circle -name brk", ["drivers.ptu.time_scale=0.5"], wait_for="view 2/",
                       params={"goal": [1.5, 0.0], "name": "brk"}, again=None),
    # The stereo twins share run_dem with the ToF ones; their stereo matching is what costs, so
    # they break at the first view and are not run again.
    "dem-full": Recipe(f"dem-full -range {DEM_RANGE} -name brk", ["drivers.ptu.time_scale=0.5"],
                       wait_for="view 1/", params={"range": [-60.0, 60.0, -50.0, -30.0], "name": "brk"}),
    "dem-update": Recipe(f"dem-update -range {DEM_RANGE} -name brk", ["drivers.ptu.time_scale=0.5"],
                         setup=["dem-full -range -5,5,-45,-40 -name base"], wait_for="view 1/",
                         params={"range": [-60.0, 60.0, -50.0, -30.0], "name": "brk"}),
    # A hardware job first, so that continue checks the devices rather than re-opening them: a
    # break while the PTU re-opens stores ptu: null (reported), which this test is not about.
    "continue": Recipe("continue", setup=["move-ptu -pan 1"], again="continue"),
    "reset": Recipe("reset", again="reset"),
    "reinit": Recipe("reinit", params={"device": "all"}, again="reinit -device tof"),  # all: long enough to be caught
    # a one-view job recorded first, then re-run offline: quick, so job and break go in one segment
    "prox": Recipe("prox -from dem/src -set cell=0.02", setup=["dem-full-tof -range -20,20,-50,-30 -cell 0.05 -name src"],
                   params={"script": "dem"}),
    # a set that holds a map, so that recover reads its layers (a bare pose set is applied in
    # microseconds, before any break can reach it)
    "recover": Recipe("recover -set last", setup=["dem-full-tof -range -20,20,-50,-30 -cell 0.05 -name src", "break",
                                                  "continue"], params={"set": "last"}, again="recover"),
}

JOB_KINDS = sorted(name for name, cmd in COMMANDS.items() if cmd.job)


def test_recipes_cover_the_jobs_help_lists(server_factory) -> None:
    c = server_factory().client()
    listed = c.request("help").fields["commands"].split()
    jobs = sorted(n for n in listed if c.request(f"help {n}").fields["kind"] == "job")
    assert jobs == sorted(n for n in JOB_KINDS if n in listed)


def finals_of(c: LineClient, tags: set[str], timeout: float, progress: list[Reply] | None = None,
              order: list[str] | None = None) -> dict[str, tuple[Reply, float]]:
    """Read until each tag has its final line; (reply, arrival time) per tag. PROGRESS lines go
    to ``progress``, the tags in the order their final lines came to ``order``."""
    got: dict[str, tuple[Reply, float]] = {}
    while not tags <= set(got):
        r = c.reply(timeout)
        if r.status == "PROGRESS" and r.tag in tags and progress is not None:
            progress.append(r)
        if r.status in ("OK", "ERROR") and r.tag in tags:
            got[r.tag] = (r, time.monotonic())
            if order is not None:
                order.append(r.tag)
    return got


def close(a: Any, b: Any) -> bool:
    if isinstance(b, float) and isinstance(a, int | float):
        return math.isclose(a, b, abs_tol=1e-9)
    if isinstance(b, list):
        return isinstance(a, list) and len(a) == len(b) and all(close(x, y) for x, y in zip(a, b, strict=True))
    return a == b


@pytest.mark.parametrize("kind", JOB_KINDS)
def test_break_and_continue_during(kind: str, server_factory) -> None:
    recipe = RECIPES.get(kind, Recipe(kind))
    srv = server_factory(recipe.overrides)
    c, b = srv.client(timeout=300), srv.client(timeout=30)
    assert b.request(POSE[0]).status == "OK"
    for line in recipe.setup:
        r = c.request(line, timeout=300)
        assert r.status == "OK", (line, r)

    progress: list[Reply] = []  # the job's PROGRESS lines
    order: list[str] = []  # which final line came first on the job's connection: brk, then job
    if recipe.wait_for is None:
        # A job of a few milliseconds may end before the break is dispatched (the job thread
        # starts at once): then break must say interrupted=none. Try until one is caught.
        for _ in range(8):
            t0 = time.monotonic()
            order.clear()
            c.send(f"@job {recipe.start}\n@brk break")
            got = finals_of(c, {"job", "brk"}, 120, order=order)
            final, t_final = got["job"]
            brk = got["brk"][0]
            if final.status == "ERROR":
                break
            assert final.status == "OK" and brk.fields["interrupted"] == "none", (final, brk)
            assert c.request("continue").status == "OK"
        else:
            pytest.fail(f"{kind} always ended before the break reached it; give it a recipe that keeps it running")
        job = final.fields["job"]
    else:
        c.send(f"@job {recipe.start}")
        while True:
            r = c.reply(300)
            if r.tag == "job" and r.status == "ACK":
                job = r.fields["job"]
                if recipe.wait_for == "":
                    time.sleep(0.2)
                    break
            elif r.tag == "job" and r.status in ("OK", "ERROR"):
                pytest.fail(f"{kind} ended before the break ({r}); change its recipe")
            elif r.tag == "job" and r.status == "PROGRESS":
                progress.append(r)
                if recipe.wait_for in r.fields.get("message", ""):
                    break
        busy = b.request("@busy continue")
        assert busy.fields["code"] == "E_BUSY" and busy.fields["job"] == job, busy
        t0 = time.monotonic()
        c.send("@brk break")
        got = finals_of(c, {"job", "brk"}, 120, progress, order)
        brk, (final, t_final) = got["brk"][0], got["job"]
    latency = t_final - t0
    record("break", kind=kind, latency_s=round(latency, 3), within=latency <= BREAK_WITHIN,
           ok_s=round(got["brk"][1] - t0, 3))
    assert final.status == "ERROR" and final.fields["code"] == "E_INTERRUPTED", final
    assert order == ["brk", "job"], f"{kind}: break's OK must come before the job's ERROR, got {order}"
    # stopped before the end: its last PROGRESS line had not reached its total (one that ran on
    # to the end would report the last step of its last phase done)
    steps = [(int(r.fields["done"]), int(r.fields["total"])) for r in progress if "total" in r.fields]
    assert not steps or steps[-1][0] < steps[-1][1], (kind, steps)
    assert brk.status == "OK" and brk.fields["interrupted"] == job, brk

    # the recovery set: complete, and it loads back
    rec = brk.fields["recovery"]
    manifest = yaml.safe_load((srv.data / rec / "manifest.yaml").read_text())
    assert not [p for p in (srv.data / "recovery").iterdir() if p.name.startswith(".")]  # no half-written set
    assert manifest["job"]["id"] == int(job) and manifest["job"]["command"] == kind
    for key, value in recipe.params.items():
        assert close(manifest["job"]["parameters"].get(key), value), (key, manifest["job"]["parameters"])
    assert manifest["pose"] == POSE[1]
    ptu = manifest["ptu"]
    assert isinstance(ptu, dict) and all(isinstance(ptu[k], float) and math.isfinite(ptu[k]) for k in ("pan", "tilt"))
    st = b.request("status")
    assert st.fields["mode"] == "break" and st.fields["recovery"] == rec and st.fields["job"] == "none"
    assert b.request("pose -x 9 -y 9 -heading 0").status == "OK"  # moved on since the break...
    loaded = b.request(f"recover -set {rec.split('/')[-1]}")
    assert loaded.status == "OK" and loaded.fields["recovery"] == rec, loaded
    assert loaded.fields["pose"] == "1.250,-0.500,15.00" and loaded.fields["interrupted_job"] == kind
    assert b.request("pose").fields["x"] == "1.250"  # ...and the set brought the pose back

    # continue: ready again, and the same kind of job runs
    r = b.request("continue")
    assert r.status == "OK" and r.fields["mode"] == "ready", r
    assert b.request("status").fields["mode"] == "ready"
    if recipe.again:
        r = c.request(recipe.again, timeout=300)
        assert r.status == "OK", (recipe.again, r)
    c.close()
    b.close()


def test_break_during_a_ptu_reset_is_quick(server_factory) -> None:
    srv = server_factory(["drivers.ptu.time_scale=0.1"])  # a reset of about 2 s
    c, b = srv.client(timeout=60), srv.client()
    c.send("@job reset")
    while True:
        r = c.reply()
        if r.status == "PROGRESS" and "re-initialising ptu" in r.fields["message"]:
            break
    time.sleep(0.2)
    b.send("@brk break")
    final, _ = finals_of(c, {"job"}, BREAK_WITHIN)["job"]  # a socket timeout fails it at 1 s
    assert final.fields.get("code") == "E_INTERRUPTED", final
    assert finals_of(b, {"brk"}, 30)["brk"][0].status == "OK"
    # The unit itself goes on resetting (a D46 takes no command meanwhile): continue's device
    # check waits for the end of that reset, then the PTU is home and moves again.
    r = c.request("continue", timeout=60)
    assert r.status == "OK" and r.fields["mode"] == "ready", r
    r = c.request("move-ptu -pan 20 -tilt -10", timeout=60)
    assert r.status == "OK" and float(r.fields["pan"]) == pytest.approx(20, abs=0.1), r


def test_break_stops_only_the_job_it_caught(server_factory) -> None:
    """break cancels the job running when it came, not one started while its recovery set is
    still being written (a continue sent as soon as the interrupted job's ERROR arrives)."""
    srv = server_factory()
    c, b = srv.client(timeout=120), srv.client(timeout=30)
    assert c.request("dem-full-tof -range -20,20,-50,-30 -cell 0.05 -name held").status == "OK"  # maps to save
    c.send("@job sleep -seconds 30")
    while not (r := c.reply()).status == "ACK":
        assert r.status in ("EVENT", "PROGRESS"), r
    b.send("@brk break")
    final, _ = finals_of(c, {"job"}, 10)["job"]
    assert final.fields["code"] == "E_INTERRUPTED", final
    c.send("@go continue")
    got = finals_of(c, {"go"}, 60)["go"][0]
    assert got.status == "OK" and got.fields["mode"] == "ready", got
    brk = finals_of(b, {"brk"}, 30)["brk"][0]
    assert brk.status == "OK" and brk.fields["interrupted"] != "none", brk
    assert b.request("status").fields["mode"] == "ready"  # the continue came after the break
