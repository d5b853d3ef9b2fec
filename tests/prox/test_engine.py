"""The workflow engine: wiring, loops, conditions, progress, cancellation, the run log, rvs-prox."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from prox_workflows.algorithms.dem2hazard import HazardParams
from prox_workflows.cli.prox import main
from prox_workflows.engine import (
    Cancelled,
    ScriptError,
    WorkflowError,
    compose,
    run_workflow,
    script_parameters,
    validate,
)
from prox_workflows.grid import GridGeometry, Layers
from prox_workflows.steps.dem import SensorFusion, SpikeRemoval
from rvs_params import SettingError, Settings, param

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


SPIKES = {"name": "despike", "inputs": {"layers": "Layers"}, "outputs": ["despiked"],
          "steps": [{"step": "remove_spikes_layers", "in": {"layers": "@layers"}, "out": "despiked"}]}


def _spiked() -> Layers:
    """Flat ground, well measured, with one lone cell 0.2 m up seen by one point."""
    dem = np.zeros((20, 20), np.float32)
    dem[10, 10] = 0.2
    count = np.full((20, 20), 10, np.int32)
    count[10, 10] = 1
    return Layers(GridGeometry(0.02, 0.0, 0.4, 20, 20),
                  {"dem": dem, "variance": np.full((20, 20), 1e-6, np.float32), "count": count})


def test_a_step_reads_its_own_settings_from_the_script_parameters_with_no_wiring() -> None:
    composed = script_parameters(SPIKES)
    assert composed is SpikeRemoval  # the script declares nothing else
    ws, _ = run_workflow(SPIKES, None, {"layers": _spiked()})
    assert np.isnan(ws["despiked"]["dem"][10, 10])  # 0.2 m > spike_jump 0.05: a spike
    ws, _ = run_workflow(SPIKES, {"spike_jump": 0.5}, {"layers": _spiked()})
    assert ws["despiked"]["dem"][10, 10] == pytest.approx(0.2)  # the caller's value reached the step
    with pytest.raises(SettingError, match="spike_jump is 5, out of range"):
        run_workflow(SPIKES, {"spike_jump": 5.0}, {"layers": _spiked()})  # checked by its declaration (max 2)


def test_a_wired_settings_mapping_replaces_the_parameters_and_is_no_parameter_of_the_script() -> None:
    wired = {**SPIKES, "steps": [{"step": "remove_spikes_layers", "in": {"layers": "@layers",
                                                                         "settings": {"spike_jump": 0.5}},
                                  "out": "despiked"}]}
    assert script_parameters(wired) is None
    ws, _ = run_workflow(wired, None, {"layers": _spiked()})
    assert ws["despiked"]["dem"][10, 10] == pytest.approx(0.2)
    bad = {**SPIKES, "steps": [{**wired["steps"][0], "in": {"layers": "@layers", "settings": {"spike_jmp": 1}}}]}
    with pytest.raises(SettingError, match="unknown key 'spike_jmp'"):
        run_workflow(bad, None, {"layers": _spiked()})


def test_two_declarations_of_one_parameter_are_refused_and_a_caller_class_must_hold_the_step_settings() -> None:
    @dataclass
    class Own(Settings):
        spike_jump: float = param(0.1, "a second declaration")

    with pytest.raises(WorkflowError, match="'spike_jump' is declared by both Own and SpikeRemoval"):
        compose(Own, (SpikeRemoval,))
    with pytest.raises(ScriptError, match=r"reads its settings \(spike_jump, spike_sigma, spike_points\)"):
        validate(SPIKES, workspace=["layers"], param_cls=HazardParams)


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
    assert spec.inputs["within_scan"] == "str" and spec.required == {"dems", "base", "rule", "cell"}
    assert spec.settings is SensorFusion and spec.inputs["settings"] == "dict?"  # its own, not a wire's
