"""Validation: a broken script is refused whole, before its first step runs, and every message
names the script line and the fix. Cheap: nothing here runs a step."""

from __future__ import annotations

import asyncio
import shutil
from pathlib import Path

import pytest

from prox_workflows import engine
from prox_workflows.cli.prox import main
from prox_workflows.engine import ScriptError, loader, validate
from prox_workflows.engine import run as engine_run

GOOD = """\
name: broken
params: dem
inputs: {views: "list[View]", out_dir: path}
outputs: [files]
steps:
  - step: view_dem
    foreach: "@views"
    in: {view: "@item", cell: $cell}
    out: view_dems
  - step: mosaic
    in: {dems: "@view_dems", base: null, rule: $rule, cell: $cell, within_scan: higher}
    out: mosaic
  - step: fill_holes_layers
    in: {layers: "@mosaic", radius: $fill_radius}
    out: filled
  - step: write_products
    phase: write
    in: {layers: "@filled", out_dir: "@out_dir", name: $name}
    out: files
"""

# (what is wrong, text to replace, its replacement, the line it is on (a text on it; None: the
# script as a whole), what the message must say)
BROKEN = [
    ("unknown step", "step: view_dem", "step: view_dme", "step: view_dme", "did you mean 'view_dem'"),
    ("unknown input", "cell: $cell}\n    out: view_dems", "cel: $cell}\n    out: view_dems", "step: view_dem",
     "has no input 'cel'; did you mean 'cell'"),
    ("missing input", 'in: {view: "@item", cell: $cell}', "in: {cell: $cell}", "step: view_dem",
     "needs input(s) view; add them under in:"),
    ("value nobody makes", '{dems: "@view_dems"', '{dems: "@view_dem"', "step: mosaic",
     "reads @view_dem, which no step makes"),
    ("value used before it is made", '{dems: "@view_dems"', '{dems: "@filled"', "step: mosaic",
     "reads @filled before a step makes it; move this step after"),
    ("literal of the wrong type", 'cell: $cell}\n    out: view_dems', 'cell: fine}\n    out: view_dems',
     "step: view_dem", "wants float but the literal 'fine' is str"),
    ("value of the wrong type", '{layers: "@mosaic", radius', '{layers: "@view_dems", radius',
     "step: fill_holes_layers", "wants Layers but @view_dems is list[Layers?]"),
    ("parameter of the wrong type", "radius: $fill_radius", "radius: $rule", "step: fill_holes_layers",
     "wants float but $rule is str"),
    ("unused output", "  - step: mosaic", "  - step: scan_rule\n    in: {views: \"@views\"}\n    out: rule\n"
     "  - step: mosaic", "step: scan_rule", "output 'rule' is never used; read it in a later step"),
    ("a number where a step's own settings go", "within_scan: higher}", "within_scan: higher, settings: 2}",
     "step: mosaic", "input settings of mosaic wants dict? but the literal 2 is int"),
    ("parameter nobody supplies", "radius: $fill_radius", "radius: $fill_radiu", "step: fill_holes_layers",
     "$fill_radiu, which no one supplies; did you mean 'fill_radius'"),
    ("second default in the script", "params: dem", "params: {cell: 0.02}", None,
     "declared once, in its parameter class"),
    ("unknown parameter class", "params: dem", "params: dme", None, "no parameter class 'dme'"),
    ("step without a name", "  - step: fill_holes_layers", "  - stp: fill_holes_layers", "stp: fill_holes_layers",
     "a step without a name; write '- step: NAME'"),
    ("misspelt step key", "    out: filled", "    outs: filled", "step: fill_holes_layers",
     "unknown key 'outs' in a step; did you mean 'out'"),
    ("@item outside a foreach", "base: null", 'base: "@item"', "step: mosaic", "reads @item outside a foreach"),
    ("more outputs than the step makes", "    out: mosaic", "    out: [mosaic, extra]", "step: mosaic",
     "makes 1 output(s) (mosaic) but out: names 2"),
    ("split phase", "    foreach: \"@views\"", "    phase: write\n    foreach: \"@views\"", "step: write_products",
     "phase 'write' is split"),
    ("foreach over a number", 'foreach: "@views"', "foreach: 3", "step: view_dem", "foreach wants a list"),
    ("condition on an unknown parameter", "    out: filled", "    out: filled\n    when: $quick",
     "step: fill_holes_layers", "$quick, which no one supplies"),
    ("input the caller does not supply", "out_dir: path}", "out_dir: path, base: Layers}", None,
     "input 'base' (Layers) is declared under inputs: but the caller does not supply it"),
    ("outputs: names what nothing makes", "outputs: [files]", "outputs: [files, dem]", None,
     "outputs: lists 'dem', which no step makes"),
    ("unknown script key", "outputs: [files]", "outputs: [files]\nparam: dem", None, "unknown script key 'param'"),
]


@pytest.fixture
def no_step_runs(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    ran: list[str] = []

    def spy(name: str, extra=None):  # noqa: ANN001, ANN202
        ran.append(name)
        raise AssertionError(f"step {name} was reached")

    monkeypatch.setattr(engine_run, "resolve_step", spy)
    return ran


def test_the_good_script_is_valid(tmp_path: Path) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text(GOOD)
    validate(path, workspace=["views", "out_dir"])


@pytest.mark.parametrize("what,old,new,line,message", BROKEN, ids=[b[0] for b in BROKEN])
def test_a_broken_script_is_refused_before_any_step_with_line_and_fix(
        tmp_path: Path, no_step_runs: list[str], what: str, old: str, new: str, line: str | None,
        message: str) -> None:
    assert old in GOOD, what
    text = GOOD.replace(old, new, 1)
    path = tmp_path / "broken.yaml"
    path.write_text(text)
    with pytest.raises(ScriptError) as err:
        engine.run_workflow(path, {"name": "x"}, {"views": [], "out_dir": tmp_path})
    assert no_step_runs == []
    problems = err.value.problems
    hits = [p for p in problems if message in p]
    assert hits, (what, problems)
    if line is not None:
        number = next(i for i, t in enumerate(text.splitlines(), 1) if line in t)
        assert hits[0].startswith(f"broken.yaml:{number}:"), (hits[0], number)
    else:
        assert hits[0].startswith("broken.yaml"), hits[0]


def test_rvs_prox_validate_says_what_and_where(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "broken.yaml"
    path.write_text(GOOD.replace("step: mosaic", "step: mosiac"))
    assert main([str(path), "--validate"]) == 1
    err = capsys.readouterr().err
    assert "broken.yaml:10: unknown step 'mosiac'; did you mean 'mosaic'?" in err, err
    assert main(["dem", "--validate"]) == 0
    assert main(["dem_views", "--validate"]) == 0
    assert "valid" in capsys.readouterr().out


def test_the_server_refuses_to_start_with_a_broken_command_script(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from rvs_server.main import StartupError, build_config, run

    scripts = tmp_path / "scripts"
    shutil.copytree(engine.SCRIPTS_DIR, scripts)
    chain = scripts / "dem_chain.yaml"
    chain.write_text(chain.read_text().replace("step: fill_holes_layers", "step: fill_hole_layers"))
    monkeypatch.setattr(loader, "SCRIPTS_DIR", scripts)
    store = build_config(None, [f"server.data={tmp_path / 'data'}", "server.port=0", "server.warm_up=false"])
    with pytest.raises(StartupError) as err:
        asyncio.run(run(store, handle_signals=False))
    text = str(err.value)
    assert "workflow script is broken" in text and "unknown step 'fill_hole_layers'" in text, text
    line = next(i for i, t in enumerate(chain.read_text().splitlines(), 1) if "fill_hole_layers" in t)
    assert f"dem_chain.yaml:{line}:" in text and "did you mean 'fill_holes_layers'" in text


@pytest.mark.parametrize("name", sorted(p.stem for p in engine.SCRIPTS_DIR.glob("*.yaml")))
def test_every_packaged_script_is_valid(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([name, "--validate"]) == 0, capsys.readouterr().err
