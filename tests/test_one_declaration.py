"""Every workflow parameter has one declaration (the script's own class, or the settings class of
the one step that reads it), and every entry point that runs a script sees that declaration's
default: the server's commands, rvs-prox, the re-run of a recorded job, and the CLIs."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import fields
from pathlib import Path

import pytest

from prox_workflows.cli import dem2hazard, dem_import, dem_mosaik, path_planner
from prox_workflows.cli.path_planner import build_parser
from prox_workflows.cli.prox import main as rvs_prox
from prox_workflows.engine import SCRIPTS_DIR, load_script, registry, script_parameters, step_settings
from prox_workflows.parameters import DemParams, DemStereoParams
from prox_workflows.params import PARAMETER_SETS, show_value
from prox_workflows.reprocess import RecordedJob
from rvs_params import Settings
from rvs_server.commands.dem import (
    Dem2HazardConfig,
    DemStereoConfig,
    DemTofConfig,
    DemUpdateStereoConfig,
    DemUpdateTofConfig,
)
from rvs_server.navigation.config import NavigateConfig

SCRIPTS = sorted(p.stem for p in SCRIPTS_DIR.glob("*.yaml"))


def _declarers(script: str) -> dict[str, list[str]]:
    """Each parameter the script reads, with every class that declares it."""
    loaded = load_script(script)
    registry()
    own = PARAMETER_SETS.get(loaded["params"]) if isinstance(loaded.get("params"), str) else None
    out: dict[str, list[str]] = defaultdict(list)
    for cls in ([own] if own is not None else []) + list(step_settings(loaded)):
        for f in fields(cls):
            out[f.name].append(cls.__name__)
    return out


def _same_defaults(got: Settings, want: type[Settings]) -> None:
    expected = want()
    differ = {f.name: (getattr(got, f.name), getattr(expected, f.name)) for f in fields(want)
              if getattr(got, f.name) != getattr(expected, f.name)}
    assert not differ, differ


@pytest.mark.parametrize("script", SCRIPTS)
def test_every_parameter_of_a_script_has_one_declaration_and_a_step_setting_is_never_rewired(script: str) -> None:
    declarers = _declarers(script)
    assert {k: v for k, v in declarers.items() if len(v) > 1} == {}
    composed = script_parameters(script)
    names = {f.name for f in fields(composed)} if composed is not None else set()
    assert names == set(declarers)
    loaded = load_script(script)
    wired = {v[1:] for s in loaded["steps"] for v in (s.get("in") or {}).values()
             if isinstance(v, str) and v.startswith("$")}
    for cls in step_settings(loaded):
        assert not wired & set(cls.specs()), f"{script} wires {cls.__name__}'s settings by hand"


def test_the_dem_chain_reads_the_settings_its_steps_declare() -> None:
    """The spike, fusion and correlation settings live beside their steps, not in DemParams, and
    still reach every DEM script and command."""
    own = {f.name for f in fields(DemParams)}
    for name in ("spike_jump", "fuse_gate", "tof_cell_correlation", "stereo_fuse_scatter"):
        assert name not in own
        for script in ("dem", "dem_views", "dem_chain"):
            assert name in {f.name for f in fields(script_parameters(script))}
        assert hasattr(DemTofConfig(), name) and hasattr(DemStereoConfig(), name)


@pytest.mark.parametrize("config,script,own", [
    (DemTofConfig, "dem", None), (DemUpdateTofConfig, "dem", None),
    (DemStereoConfig, "dem", DemStereoParams), (DemUpdateStereoConfig, "dem", DemStereoParams),
    (Dem2HazardConfig, "dem2hazard", None),
], ids=lambda v: getattr(v, "__name__", str(v)))
def test_the_server_commands_see_the_script_defaults(config: type[Settings], script: str,
                                                     own: type[Settings] | None) -> None:
    composed = script_parameters(script, own)
    assert composed is not None and issubclass(config, composed)
    _same_defaults(config(), composed)


@pytest.mark.parametrize("script", ["plan_leg", "path_planner"])
def test_navigate_and_rvs_path_planner_see_the_plan_scripts_defaults(script: str) -> None:
    composed = script_parameters(script)
    _same_defaults(NavigateConfig().plan, composed)
    args = build_parser().parse_args(["--hazard", "h.tif", "--slope", "s.tif", "--start", "0,0", "--goal", "1,1",
                                      "-o", "x"])
    for name, spec in composed.specs().items():
        assert spec.parse(str(getattr(args, name))) == spec.default, name


@pytest.mark.parametrize("made_by,own", [("dem-full-tof", DemParams), ("dem-full", DemStereoParams)])
def test_a_rerun_of_a_recorded_job_sees_the_commands_defaults(tmp_path: Path, made_by: str,
                                                              own: type[Settings]) -> None:
    job = RecordedJob(views=tmp_path / "site_views", name="site", made_by=made_by)
    _same_defaults(job.param_class()(), script_parameters("dem", own))


@pytest.mark.parametrize("script", [s for s in SCRIPTS if script_parameters(s) is not None])
def test_rvs_prox_help_lists_every_parameter_with_its_declared_default(script: str,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    assert rvs_prox([script, "--help"]) == 0
    text = capsys.readouterr().out
    for name, spec in script_parameters(script).specs().items():
        shown = show_value(spec.default)
        assert f"  {name}: {spec.describe()}{f'; default {shown}' if shown else ''}: " in text, name


@pytest.mark.parametrize("cli,script", [(dem_import, "dem_import"), (dem_mosaik, "dem_mosaik"),
                                        (dem2hazard, "dem2hazard"), (path_planner, "path_planner")],
                         ids=lambda v: v if isinstance(v, str) else "")
def test_each_cli_offers_every_parameter_of_its_script(cli: object, script: str,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        cli.main(["--help"])  # type: ignore[attr-defined]
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps its lines
    for name in script_parameters(script).specs():
        assert "--" + name.replace("_", "-") in text, name
    assert "None" not in text  # an option without a default says what happens instead
