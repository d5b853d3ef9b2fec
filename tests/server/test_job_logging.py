"""Log context in job and monitor threads: every line a job's worker thread or a
monitor's thread writes to the JSON log file says which request it belongs to, as the event
loop's lines do, through a real TCP socket and the real log file."""

from __future__ import annotations

import json
import time
from typing import Any

from support.server import wait_for


def _log(srv: Any) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (srv.data / "rvs.log").read_text().splitlines() if line.strip()]


def test_every_line_of_a_job_or_monitor_thread_carries_its_request(server: Any, client: Any) -> None:
    requests = [
        ("g1", "grab-tof -type amplitude -output lg"),
        ("d1", "dem-full-tof -range -20,20,-40,-30 -name lg -integrate 1 -mesh false"),
        ("f1", "sim fault -device tof -kind unplug"),
        ("g2", "grab-tof -output lg2"),  # E_DEVICE: the server is in fault mode
        ("r1", "reset"),  # re-opens the ToF camera in the job's thread: the device registry logs it
    ]
    for tag, line in requests:
        client.send(f"@{tag} {line}")
        final = client.until_final(timeout=120)[-1]
        assert final.tag == tag, final
    assert final.status == "OK", final
    client.send("@h1 hazard-start -period 0.05")
    assert client.until_final()[-1].status == "OK"
    assert wait_for(lambda: server.app.monitors["hazard"].cycles >= 2, timeout=60)
    client.send("@h2 hazard-stop")
    assert client.until_final()[-1].status == "OK"
    time.sleep(0.05)  # the file handler writes as the line is logged; this only spares a flush race

    lines = _log(server)
    jobs = {line["tag"]: line["job"] for line in lines if line.get("event") == "job_start"}
    assert set(jobs) == {"g1", "d1", "g2", "r1"}
    in_jobs = [line for line in lines if line["thread"].startswith("rvs-job")]
    assert in_jobs, "reset re-opens the ToF camera in its job's thread, and the device registry logs that"
    for line in in_jobs:
        assert line.get("tag") in jobs and line.get("job") == jobs[line["tag"]], line
        assert line.get("conn") is not None and line.get("command"), line
    in_monitor = [line for line in lines if line["thread"] == "rvs-hazard"]
    assert {"monitor_start", "monitor_end"} <= {line["event"] for line in in_monitor}
    for line in in_monitor:
        assert line.get("tag") == "h1" and line.get("command") == "hazard-start", line
        assert line.get("monitor") == "hazard" and line.get("conn") is not None, line
    # and the event loop's lines about a job carry the same context, as before
    for line in lines:
        if line.get("event") in ("job_start", "job_ok", "job_error"):
            assert line.get("tag") in jobs and line.get("job") == jobs[line["tag"]], line
