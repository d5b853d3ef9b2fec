"""How a job ended, for a client that was not there to see it: ``status -job N`` and the last
job in ``status``, over real sockets."""

from __future__ import annotations

import json

import pytest
from support.server import wait_for

from rvs_server.jobs import HISTORY


def test_a_reconnecting_client_learns_how_its_orphaned_job_ended(server) -> None:
    gnc = server.client()
    ok = gnc.start_job("@mine sleep -seconds 0.3")
    gnc.close()  # the link drops while the job runs; the job runs on
    gnc = server.client()
    assert wait_for(lambda: gnc.request(f"status -job {ok}").fields["job_state"] != "running")
    r = gnc.request(f"status -job {ok}")
    assert r.status == "OK" and r.fields["job"] == ok and r.fields["job_command"] == "sleep", r
    assert r.fields["job_state"] == "ok" and r.fields["job_tag"] == "mine"
    assert r.fields["final_status"] == "OK" and float(r.fields["final_slept"]) >= 0.3, r
    st = gnc.request("status")
    assert (st.fields["job"], st.fields["last_job"], st.fields["last_job_outcome"]) == ("none", ok, "OK"), st

    # an interrupted one: started, orphaned, broken from another connection
    owner = server.client()
    stopped = owner.start_job("sleep -seconds 30")
    running = gnc.request(f"status -job {stopped}")
    assert running.fields["job_state"] == "running" and "final_status" not in running.fields, running
    owner.close()
    assert gnc.request("break").fields["interrupted"] == stopped
    assert wait_for(lambda: gnc.request(f"status -job {stopped}").fields["job_state"] == "error")
    r = gnc.request(f"status -job {stopped}")
    assert (r.fields["final_status"], r.fields["final_code"]) == ("ERROR", "E_INTERRUPTED"), r
    st = gnc.request("status")
    assert (st.fields["last_job"], st.fields["last_job_command"], st.fields["last_job_outcome"]) == (
        stopped, "sleep", "E_INTERRUPTED"), st
    assert gnc.request(f"status -job {ok}").fields["final_status"] == "OK"  # the earlier one is still kept


def test_status_job_in_json_nests_the_final_line(server) -> None:
    c = server.client()
    c.send("format json")
    c.line()  # format's OK
    c.line()  # the JSON greeting
    job = c.until_final(job=c.start_job("move-ptu -pan 5"))[-1].fields["job"]
    c.send(f"status -job {job}")
    while (obj := json.loads(c.line()))["module"] != "EGP-RVS-STATUS":
        assert obj["status"] == "EVENT", obj
    assert obj["job"] == job and obj["job_state"] == "ok", obj
    assert obj["final"]["status"] == "OK" and obj["final"]["pan"] == pytest.approx(5, abs=0.1), obj


def test_status_job_keeps_the_last_jobs_and_says_which_it_does_not_know(server) -> None:
    c = server.client()
    assert c.request("status").fields["last_job"] == "none"
    r = c.request("status -job 1")
    assert r.fields["code"] == "E_DATA" and "no job 1" in r.fields["message"], r
    ids = []
    for _ in range(HISTORY + 1):
        r = c.until_final(job=c.start_job("sleep -seconds 0"))[-1]
        assert r.status == "OK"
        ids.append(r.fields["job"])
    r = c.request(f"status -job {ids[0]}")  # the oldest has been let go
    assert r.status == "ERROR" and r.fields["code"] == "E_DATA" and str(HISTORY) in r.fields["message"], r
    assert c.request(f"status -job {ids[1]}").fields["final_status"] == "OK"
    assert c.request(f"status -job {ids[-1]}").fields["final_status"] == "OK"
    r = c.request(f"status -job {int(ids[-1]) + 1}")
    assert r.fields["code"] == "E_DATA", r
