"""navigate's wait for a GNC that drives the rover itself, through real sockets: a GNC slow to
start keeps its leg, a GNC that never leaves the start or whose connection is gone ends the job
with an error that says what to do, instead of a job left running forever."""

from __future__ import annotations

import time

from support.marks import long_test
from support.server import LineClient, wait_for, waiting_event

from rvs_server.navigation.config import NavigateConfig
from rvs_server.protocol import Reply

# the legs scan 120 degrees towards the goal, not 360: the wait is what these tests are about
NARROW = "navigate.range=-90,30,-50,-10"


@long_test  # 8-9 s: CI's long suite runs it; the GNC that never leaves the start runs by default
def test_a_gnc_that_reports_its_start_pose_before_driving_keeps_its_leg(server_factory) -> None:
    """Ten unchanged reports of the start at 4 Hz (2.5 s, longer than pose_settle) are a GNC
    getting ready: the leg waits for it to drive, and the navigate ends in that one leg."""
    srv = server_factory(["server.scene=office", NARROW])
    c, gnc = srv.client(), srv.client()
    job = c.start_job("navigate -goal 1.5,-1.2 -loop scan -scan-plan circle -name slow")
    event = waiting_event(gnc)
    assert event.fields["leg"] == "1"
    wps = [float(v) for v in event.fields["waypoints"].split(",")]
    start, end = wps[0:2], wps[-3:-1]
    for _ in range(10):
        assert gnc.request(f"pose -x {start[0]} -y {start[1]} -heading 0").status == "OK"
        time.sleep(0.25)
    st = gnc.request("status")
    assert st.fields["job"] == job and st.fields["phase"] == "drive", st.fields
    assert srv.app.jobs.current is not None and srv.app.jobs.current.context == {"leg": 1}
    # now it drives, and stands at the leg's end
    for f in (0.3, 0.6, 1.0):
        x, y = start[0] + f * (end[0] - start[0]), start[1] + f * (end[1] - start[1])
        assert gnc.request(f"pose -x {x:.3f} -y {y:.3f} -heading 0").status == "OK"
    srv.app.world.set_rover_pose(end[0], end[1], 0.0)
    final = c.until_final(job=job, timeout=300)[-1]
    assert final.status == "OK" and final.fields["reached"] == "true", final.fields
    assert final.fields["legs"] == "1", final.fields


@long_test  # guards kept behaviour (it passed before the hold rule changed): CI's long suite runs it
def test_stopped_at_the_start_still_ends_the_leg_at_once(server_factory) -> None:
    """-stopped true is the GNC's word that the rover stands: it ends the wait even where the leg
    started (a GNC that cannot drive the leg), and navigate scans again."""
    srv = server_factory(["server.scene=office", NARROW])
    c, gnc = srv.client(), srv.client()
    job = c.start_job("navigate -goal 1.5,-1.2 -loop scan -scan-plan circle -name givesup")
    assert waiting_event(gnc).fields["leg"] == "1"
    assert gnc.request("pose -stopped true").fields["stopped"] == "true"
    assert waiting_event(gnc).fields["leg"] == "2"
    assert c.request("break").status == "OK"
    assert c.until_final(job=job)[-1].fields["code"] == "E_INTERRUPTED"


def test_the_wait_for_the_gnc_has_a_timeout_by_default() -> None:
    assert NavigateConfig().wait_timeout > 0


def test_a_gnc_that_never_leaves_the_start_ends_navigate_with_what_to_do(server_factory) -> None:
    srv = server_factory(["server.scene=office", NARROW, "navigate.wait_timeout=3"])
    c, gnc = srv.client(), srv.client()
    job = c.start_job("navigate -goal 1.5,-1.2 -loop scan -scan-plan circle -name stays")
    waiting_event(gnc)
    for _ in range(16):  # 4 s of the standing pose at 4 Hz: alive, but not driving
        assert gnc.request("pose -x 0 -y 0 -heading 0").status == "OK"
        time.sleep(0.25)
    final = c.until_final(job=job, timeout=60)[-1]
    assert final.status == "ERROR" and final.fields["code"] == "E_DATA", final.fields
    msg = final.fields["message"]
    assert "did not leave the leg's start (0.00, 0.00) within 3 s" in msg, msg
    assert "navigate.wait_timeout" in msg and "pose -stopped true" in msg, msg
    assert gnc.request("status").fields["mode"] == "ready"


def _final_of(c: LineClient, job: str, timeout: float = 60.0) -> Reply:
    """status -job N until job N has ended (its own connection is gone)."""
    reply: list[Reply] = []

    def ended() -> bool:
        r = c.request(f"status -job {job}")
        reply[:] = [r]
        return r.fields.get("job_state") != "running"

    assert wait_for(ended, timeout=timeout, interval=0.2), reply[0].fields
    return reply[0]


@long_test  # 6-9 s of waiting out the GNC: CI's long suite runs it; the wait's other ends run by default
def test_a_navigate_whose_connection_closed_ends_once_no_pose_comes(server_factory) -> None:
    """The requester's connection closes while its leg waits (wait_timeout off, so only the
    disconnect can end it): a pose streamed from another connection keeps the job; once none
    comes for pose_settle, it ends E_DATA, and status -job tells why."""
    srv = server_factory(["server.scene=office", NARROW, "navigate.wait_timeout=0"])
    c, gnc = srv.client(), srv.client()
    job = c.start_job("navigate -goal 1.5,-1.2 -loop scan -scan-plan circle -name orphan")
    waiting_event(gnc)
    c.close()
    for i in range(12):  # 3 s of a GNC on another connection driving at 4 Hz
        assert gnc.request(f"pose -x {0.02 * i:.3f} -y 0 -heading 0").status == "OK"
        time.sleep(0.25)
    st = gnc.request("status")
    assert st.fields["job"] == job and st.fields["phase"] == "drive", st.fields
    final = _final_of(gnc, job)
    assert final.fields["job_state"] == "error" and final.fields["final_code"] == "E_DATA", final.fields
    msg = final.fields["final_message"]
    assert "the connection that started navigate closed and no pose came for 2 s" in msg, msg
    assert "start navigate again from the GNC's connection" in msg, msg
    assert gnc.request("status").fields["mode"] == "ready"
