"""Soak: tools/soak.py, run as the program it is (``python -m tools.soak`` from the repository),
against a simulated server in a child process: 20
clients of mixed traffic (valid and invalid requests, jobs, breaks, continues, format and
events switches). Every request answered, resident memory grows under 10 % after the warm-up,
no file descriptor leaks, the server still alive and stopping cleanly.

About 16 s in the regular suite (memory growth under 25 % there: a smoke check); 10 minutes after
a one-minute warm-up with RVS_LONG=1, memory growth under 10 %.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from support.marks import long_suite, long_test
from support.reliability_figures import record

ROOT = Path(__file__).resolve().parents[2]


def soak(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "tools.soak", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=1500)


def run(tmp_path: Path, seconds: float, warmup: float, max_growth: float) -> dict:
    out = tmp_path / "soak.json"
    rc = soak("--seconds", str(seconds), "--warmup", str(warmup), "--clients", "20", "--quiet",
              "--data", str(tmp_path / "data"), "--json", str(out), "--max-growth", str(max_growth)).returncode
    result = json.loads(out.read_text())
    record("soak", **{k: v for k, v in result.items() if k not in ("codes", "rss_timeline_mib")},
           codes=result["codes"])
    # the timeline tells a leak (a steady climb) from a heap still settling (a step, then flat)
    assert rc == 0, (result["problems"], result.get("rss_timeline_mib"))
    assert result["requests"] > 0 and result["unanswered"] == 0
    assert result["jobs"] > 0 and result["codes"].get("E_INTERRUPTED", 0) > 0  # breaks met running jobs
    assert result["rss_growth"] < max_growth and result["fds_after"] <= result["fds_before"]
    return result


@long_test
def test_soak_short(tmp_path: Path) -> None:
    # Seconds after start the simulated sensors' renders still settle their memory and single
    # renders swing it by ~5 %: the short run only catches a gross leak; 10 % is the long run's.
    # (How many requests fit in the 10 s is the machine's speed: ~45,000 on an idle one. The soak
    # checks that every one was answered, whatever their number.)
    run(tmp_path, seconds=10, warmup=6, max_growth=0.25)


@long_suite
@pytest.mark.timeout(1200)  # pyproject's 300 s is for ordinary tests
def test_soak_ten_minutes(tmp_path: Path) -> None:
    run(tmp_path, seconds=600, warmup=60, max_growth=0.10)


def test_soak_refuses_bad_options() -> None:
    out = soak("--clients", "0")
    assert out.returncode == 2 and "--clients" in out.stderr, out.stderr
