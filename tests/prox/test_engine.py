"""The workflow engine: wiring, loops, conditions, progress, cancellation, the run log, rvs-prox."""

from __future__ import annotations

import pytest

from prox_workflows.engine import Cancelled, WorkflowError, main, run_workflow

SCRIPT = {
    "name": "demo",
    "params": {"scale": 2, "double": True},
    "steps": [
        {"step": "make", "in": {"n": 4}, "out": "items"},
        {"step": "times", "foreach": "@items", "in": {"x": "@item", "k": "$scale"}, "out": "scaled"},
        {"step": "total", "in": {"values": "@scaled"}, "out": ["sum", "count"]},
        {"step": "times", "in": {"x": "@sum", "k": 2}, "out": "doubled", "when": "$double"},
    ],
}
STEPS = {
    "make": lambda n: list(range(n)),
    "times": lambda x, k: x * k,
    "total": lambda values: {"sum": sum(values), "count": len(values)},
}


def test_wiring_loops_and_conditions() -> None:
    ws, log = run_workflow(SCRIPT, steps=STEPS)
    assert ws["scaled"] == [0, 2, 4, 6] and ws["sum"] == 12 and ws["count"] == 4 and ws["doubled"] == 24
    assert [e["step"] for e in log.entries] == ["make", "times", "total", "times"]
    ws, log = run_workflow(SCRIPT, {"double": False, "scale": 10}, steps=STEPS)
    assert ws["sum"] == 60 and "doubled" not in ws and log.entries[-1]["skipped"] is True


def test_progress_counts_items_and_sub_steps() -> None:
    seen: list[tuple[int, int]] = []

    def with_sub(n: int, progress=None) -> int:  # noqa: ANN001
        for i in range(n):
            progress(i + 1, n, f"sub {i}")
        return n

    script = {"steps": [{"step": "make", "in": {"n": 3}, "out": "items"},
                        {"step": "times", "foreach": "@items", "in": {"x": "@item", "k": 1}, "out": "y"},
                        {"step": "sub", "in": {"n": 5}, "out": "z"}]}
    run_workflow(script, steps={**STEPS, "sub": with_sub}, progress=lambda d, t, m: seen.append((d, t)))
    assert seen[-1] == (9, 9)  # 1 + 3 items + 5 sub-steps
    assert all(d <= t for d, t in seen) and [d for d, _ in seen] == sorted(d for d, _ in seen)


def test_cancellation_between_items() -> None:
    calls: list[int] = []

    def slow(x: int) -> int:
        calls.append(x)
        return x

    stop = {"now": False}
    script = {"steps": [{"step": "slow", "foreach": [1, 2, 3, 4], "in": {"x": "@item"}, "out": "y"}]}

    def progress(done: int, total: int, message: str) -> None:
        stop["now"] = done >= 2

    with pytest.raises(Cancelled):
        run_workflow(script, steps={"slow": slow}, progress=progress, cancelled=lambda: stop["now"])
    assert calls == [1, 2]


def test_errors_name_what_is_wrong() -> None:
    with pytest.raises(WorkflowError, match="unknown step 'nope'"):
        run_workflow({"steps": [{"step": "nope"}]})
    with pytest.raises(WorkflowError, match="no parameter 'missing'"):
        run_workflow({"steps": [{"step": "make", "in": {"n": "$missing"}}]}, steps=STEPS)
    with pytest.raises(WorkflowError, match="no workspace value 'ghost'"):
        run_workflow({"steps": [{"step": "make", "in": {"n": "@ghost"}}]}, steps=STEPS)
    with pytest.raises(WorkflowError, match="names 3 outputs"):
        run_workflow({"steps": [{"step": "make", "in": {"n": 1}, "out": ["a", "b", "c"]}]}, steps=STEPS)


def test_rvs_prox_runs_a_script_file(tmp_path, capsys) -> None:
    script = tmp_path / "ptu.yaml"
    script.write_text(
        "name: positions\nparams: {overlap: 0.2}\nsteps:\n"
        "  - step: get_ptu_positions\n"
        "    in: {view_range: $range, fov: [43.6, 34.6], overlap: $overlap}\n"
        "    out: positions\n"
    )
    assert main([str(script), "--set", "range=[-60,60,-40,-10]", "--log", str(tmp_path / "run.yaml")]) == 0
    out = capsys.readouterr().out
    assert "get_ptu_positions" in out and (tmp_path / "run.yaml").is_file()
    assert main([str(tmp_path / "missing.yaml")]) == 1
