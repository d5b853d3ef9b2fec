"""Fuzzing a live server: generated, junk and mutated request lines over 20
concurrent connections to ``rvs_server`` in a child process.

Every non-blank, non-comment request gets exactly one final line (counted per connection
against the reference model of tests/support/wire_fuzz.py, and per tag for the unmutated requests),
no reply is E_INTERNAL or unparseable, the server never dies, its resident memory stays flat
and its file descriptors come back. The short version (about 10,000 lines) runs always; the long
one (100,000 lines) with RVS_LONG=1.
"""

from __future__ import annotations

import random
import time
from collections.abc import Iterator

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from support.marks import LONG, long_suite, long_test
from support.proc_probes import Sampler, fd_count, rss_kb
from support.reliability_figures import record
from support.server import FAST, LineClient, wait_for
from support.wire_fuzz import LineGen, Plan, close_iac, drive, hazard, logical_line, make_plan, summarize

from rvs_server.client.session import ServerProcess

CONNECTIONS = 20
JOB_WARM_UP_LINES = 500  # a connection's lines in a job-heavy warm-up round
WARM_UP = [  # every variant of the jobs the fuzz may run: their first renders allocate for good
    # a current map: check-move's generated values (up to the help's extremes) then sweep it
    "dem-full-tof -range -20,20,-40,-25 -name fzmap",
    *(f"grab-stereo -output fz2 -resolution low -format {f}" for f in ("mono8", "rgb8", "mono8")),
    *(f"grab-tof -output fz{i % 2} -type {t} -integrate {i}" for i, t in
      enumerate(("amplitude", "distance", "confidence", "z", "xyz"), 1) if i <= 4),
    "grab-tof -output fz1 -type xyz -integrate 4", "move-ptu -pan 20 -tilt -20", "sim move-rover -dx 50",
    "grab-stereo -output fz2 -resolution low", "grab-tof -output fz1 -integrate 2", "sim move-rover -dx -50 -dyaw 90",
    "reset", "break", "recover", "continue", "format json", "format text",
]


@pytest.fixture(scope="module")
def server() -> Iterator[ServerProcess]:
    srv = ServerProcess(extra_args=FAST)
    srv.start()
    yield srv
    srv.stop()


def alive(srv: ServerProcess) -> bool:
    if srv.proc is None or srv.proc.poll() is not None:
        return False
    c = LineClient(srv.port)
    try:
        return c.request("@alive status").status == "OK"
    finally:
        c.close()


def at_rest_kb(srv: ServerProcess) -> int:
    """The server's resident size once no job runs (a render in flight holds tens of MB)."""
    c = LineClient(srv.port)
    try:
        assert wait_for(lambda: c.request("status").fields["job"] == "none", 60)
    finally:
        c.close()
    return rss_kb(srv.proc.pid)


def fuzz(srv: ServerProcess, lines_per_connection: int, rounds: int, seed: int, job_warmups: int) -> dict:
    """Warm-up rounds, then ``rounds`` rounds of 20 connections; fds before against after, and
    the resident size at rest (no job running) least over the warm-up's rounds against its least
    over the last half of the rounds: a leak raises that floor. One sample is no measure: after
    about one round in three the server holds 10-40 MiB more (anonymous memory, with the heap
    trimmed after every job; what holds it is not traced) until a later round gives it back:
    +15.8 % once on CI's loaded machine.

    Jobs run in worker threads; the server bounds glibc's arenas (``server.malloc_arenas``, 2),
    without which the resident size climbs in steps while more threads take their share of the
    renders (+16 % over the first rounds of job-heavy traffic, flat over the next ten). The
    warm-up runs job-heavy rounds too."""
    pid = srv.proc.pid
    c = LineClient(srv.port)  # warm-up: the first stereo render alone allocates ~100 MB for good
    for line in WARM_UP:
        assert c.request(line, timeout=60).status in ("OK", "ERROR")
    c.close()
    warm = [make_plan(LineGen(random.Random(seed * 7919 + i)), 100, f"w{i}") for i in range(CONNECTIONS)]
    for w in range(job_warmups):
        warm += [make_plan(LineGen(random.Random(seed * 6151 + w * 100 + i)), JOB_WARM_UP_LINES, f"j{w}c{i}",
                           job_share=1.0, junk_share=0.0, mutate_share=0.0) for i in range(CONNECTIONS)]
    warm_rests = []
    for k in range(0, len(warm), CONNECTIONS):
        totals = summarize(drive(srv.port, warm[k : k + CONNECTIONS], seed + k))
        assert totals["finals"] == totals["expected"] and not totals["errors"], totals
        warm_rests.append(at_rest_kb(srv))
    rss_warm = min(warm_rests)
    time.sleep(0.5)  # the warm-up connections are closed by now
    fds_before = fd_count(pid)
    sent = expected = finals = 0
    rests: list[int] = []
    failures: list[dict] = []
    t0 = time.monotonic()
    with Sampler(pid) as sampler:
        for r in range(rounds):
            plans = [make_plan(LineGen(random.Random(seed * 104729 + r * 100 + i)), lines_per_connection, f"r{r}c{i}")
                     for i in range(CONNECTIONS)]
            summary = summarize(drive(srv.port, plans, seed + r))
            sent += sum(len(p.pieces) for p in plans)
            expected += summary["expected"]
            finals += summary["finals"]
            if summary["miscounted"] or summary["errors"] or summary["missing_tags"] or summary["internal"] \
                    or summary["malformed"]:
                failures.append(summary)
            rests.append(at_rest_kb(srv))
    seconds = time.monotonic() - t0
    assert alive(srv), srv.log_tail()
    assert wait_for(lambda: fd_count(pid) <= fds_before, 60), (fd_count(pid), fds_before)
    rss_end = min(rests[len(rests) // 2 :])
    figures = {
        "lines": sent, "requests": expected, "finals": finals, "connections": CONNECTIONS, "seconds": round(seconds, 1),
        "rss_warm_kb": rss_warm, "rss_end_kb": rss_end, "rss_rests_kb": rests, "rss_peak_kb": sampler.peak_kb(),
        "rss_growth": round((rss_end - rss_warm) / rss_warm, 4), "fds_before": fds_before, "fds_after": fd_count(pid),
    }
    record("fuzz_server", **figures)
    assert not failures, [{k: v for k, v in f.items() if v} for f in failures[:2]]
    assert finals == expected
    return figures


@long_test
def test_fuzz_20_connections(server: ServerProcess) -> None:
    figures = fuzz(server, lines_per_connection=50, rounds=10, seed=1, job_warmups=1)
    assert figures["lines"] >= 10_000
    assert figures["rss_growth"] < 0.10, figures


@long_suite
@pytest.mark.timeout(1200)
def test_fuzz_100k_lines_over_20_connections(server: ServerProcess) -> None:
    figures = fuzz(server, lines_per_connection=500, rounds=10, seed=2, job_warmups=1)
    assert figures["lines"] >= 100_000
    assert figures["rss_growth"] < 0.10, figures


# ------------------------------------------------------------------------------------ hypothesis


def piece_lists(draw_rng: random.Random) -> Plan:
    gen = LineGen(draw_rng)
    plan = Plan()
    for i in range(draw_rng.randint(1, 12)):
        r = draw_rng.random()
        if r < 0.3:
            raw, tag = gen.junk().encode("utf-8", "surrogatepass"), None
        elif r < 0.7:
            raw, tag = gen.mutate(gen.request().line.encode("utf-8", "surrogatepass")), None
        else:
            tag = f"h{i}"
            raw = gen.request(tag=tag).line.encode("utf-8", "surrogatepass")
        if any(hazard(logical_line(close_iac(p))) for p in raw.split(b"\n")):
            continue
        plan.add(raw, tag, "h")
    return plan


@pytest.mark.long
@settings(max_examples=200 if LONG else 40, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
@given(st.randoms(use_true_random=False).map(piece_lists))
def test_hypothesis_batches_get_one_final_line_each(server: ServerProcess, plan: Plan) -> None:
    """The same generators under hypothesis, one connection per example: a failure shrinks to
    the few lines that cause it."""
    summary = summarize(drive(server.port, [plan], 0, timeout=60))
    assert not summary["errors"] and not summary["internal"] and not summary["malformed"], summary
    assert summary["finals"] == summary["expected"], (summary, plan.pieces)
    assert not summary["missing_tags"], summary
