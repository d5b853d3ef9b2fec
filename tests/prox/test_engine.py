"""The workflow engine: wiring, loops, conditions, progress, cancellation, the run log, rvs-prox."""

from __future__ import annotations

import pytest

from prox_workflows.cli.prox import main
from prox_workflows.engine import Cancelled, WorkflowError, run_workflow

SCRIPT = {
    "name": "demo",
    "outputs": ["scaled", "count", "doubled"],
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
    ws, log = run_workflow(SCRIPT, {"scale": 2, "double": True}, steps=STEPS)
    assert ws["scaled"] == [0, 2, 4, 6] and ws["sum"] == 12 and ws["count"] == 4 and ws["doubled"] == 24
    assert [e["step"] for e in log.entries] == ["make", "times", "total", "times"]
    ws, log = run_workflow(SCRIPT, {"double": False, "scale": 10}, steps=STEPS)
    assert ws["sum"] == 60 and "doubled" not in ws and log.entries[-1]["skipped"] is True


def test_dollar_alone_hands_a_step_all_the_parameters() -> None:
    script = {"name": "whole", "outputs": ["settings"],
              "steps": [{"step": "keep", "in": {"settings": "$"}, "out": "settings"}]}
    ws, _ = run_workflow(script, {"scale": 3, "double": False}, steps={"keep": lambda settings: settings})
    assert ws["settings"] == {"scale": 3, "double": False}


def test_progress_is_per_phase_with_a_fixed_total_and_a_growing_done() -> None:
    seen: list[tuple[str, int, int, str]] = []

    def with_sub(n: int, progress=None) -> int:  # noqa: ANN001
        progress(0, n, "starting")
        for i in range(n):
            progress(i + 1, n, f"sub {i}")
        return n

    script = {"outputs": ["z", "count", "d"], "steps": [{"step": "make", "in": {"n": 3}, "out": "items"},
                        {"step": "times", "foreach": "@items", "in": {"x": "@item", "k": 1}, "out": "y"},
                        {"step": "sub", "in": {"n": 5}, "out": "z", "phase": "acquire"},
                        {"step": "total", "in": {"values": "@y"}, "out": ["sum", "count"], "phase": "sum"},
                        {"step": "times", "in": {"x": "@sum", "k": 2}, "out": "d", "phase": "sum",
                         "when": False}]}
    run_workflow(script, steps={**STEPS, "sub": with_sub},
                 progress=lambda d, t, m, phase: seen.append((phase, d, t, m)))
    # two steps of "process" (the loop counts once), the sub-step's own five, two of "sum"
    assert [(p, d, t) for p, d, t, _ in seen] == [
        ("process", 1, 2), ("process", 2, 2),
        ("acquire", 0, 5), ("acquire", 1, 5), ("acquire", 2, 5), ("acquire", 3, 5), ("acquire", 4, 5),
        ("acquire", 5, 5),
        ("sum", 1, 2), ("sum", 2, 2)]
    assert seen[1][3] == "times x3" and seen[-1][3] == "times skipped"


def test_a_split_phase_is_refused_before_anything_runs() -> None:
    ran: list[int] = []
    script = {"outputs": ["a", "b", "c"], "steps": [{"step": "make", "in": {"n": 1}, "out": "a", "phase": "one"},
                        {"step": "make", "in": {"n": 2}, "out": "b", "phase": "two"},
                        {"step": "make", "in": {"n": 3}, "out": "c", "phase": "one"}]}
    with pytest.raises(WorkflowError, match="phase 'one' is split"):
        run_workflow(script, steps={"make": lambda n: ran.append(n) or [n]})
    assert ran == []


def test_cancellation_between_items() -> None:
    calls: list[int] = []
    stop = {"now": False}

    def slow(x: int) -> int:
        calls.append(x)
        stop["now"] = len(calls) >= 2
        return x

    script = {"steps": [{"step": "slow", "foreach": [1, 2, 3, 4], "in": {"x": "@item"}, "out": "y"}]}
    with pytest.raises(Cancelled):
        run_workflow(script, steps={"slow": slow}, cancelled=lambda: stop["now"])
    assert calls == [1, 2]


def test_errors_name_what_is_wrong() -> None:
    with pytest.raises(WorkflowError, match="unknown step 'nope'"):
        run_workflow({"steps": [{"step": "nope"}]})
    with pytest.raises(WorkflowError, match=r"parameter \$missing, which no one supplies"):
        run_workflow({"steps": [{"step": "make", "in": {"n": "$missing"}}]}, steps=STEPS)
    with pytest.raises(WorkflowError, match="reads @ghost, which no step makes"):
        run_workflow({"steps": [{"step": "make", "in": {"n": "@ghost"}}]}, steps=STEPS)
    with pytest.raises(WorkflowError, match="names 3 outputs"):  # a caller's own step declares no outputs
        run_workflow({"steps": [{"step": "make", "in": {"n": 1}, "out": ["a", "b", "c"]}]}, steps=STEPS)


def test_rvs_prox_runs_a_script_file(tmp_path, capsys) -> None:
    script = tmp_path / "ptu.yaml"
    script.write_text(
        "name: positions\nparams: dem\nsteps:\n"
        "  - step: get_ptu_positions\n"
        "    in: {view_range: $range, fov: [43.6, 34.6], overlap: $overlap}\n"
        "    out: positions\n"
    )
    assert main([str(script), "--set", "range=-60,60,-40,-10", "--log", str(tmp_path / "run.yaml")]) == 0
    out = capsys.readouterr().out
    assert "get_ptu_positions" in out and (tmp_path / "run.yaml").is_file()
    assert main([str(tmp_path / "missing.yaml")]) == 2  # no such file: the command line's fault


def test_a_steps_input_types_are_its_annotations() -> None:
    from prox_workflows.engine import registry
    from prox_workflows.engine.types import annotation_type

    assert annotation_type("str | Path | None") == "path?" and annotation_type("np.ndarray") == "array"
    assert annotation_type("list[float] | tuple[float, float, float, float]") == "floats"
    assert annotation_type("list[Layers | None]") == "list[Layers?]" and annotation_type("Sequence[str]") == "list"
    assert annotation_type("dict[str, Any] | None") == "dict?" and annotation_type("int | str") == "any"
    spec = registry()["mosaic"]
    assert spec.inputs["dems"] == "list[Layers?]" and spec.inputs["base"] == "Layers?"
    assert spec.inputs["gate"] == "float" and spec.required == {"dems", "base", "rule", "cell"}
