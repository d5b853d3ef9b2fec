"""``rvs-prox``: validate or run a workflow script (``prox_workflows/scripts``) from the command
line, re-run a recorded DEM job (``--from``), or dispatch to the campaign tools (batch,
mosaic-campaign)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from rvs_params import SettingError, Settings, assignments
from rvs_params.cli import ToolParser

from ..engine import ScriptError, WorkflowError, load_script, param_class, run_workflow, script_path, validate
from ..params import show_value
from .progress import show_progress


def params_help(cls: type[Settings] | None) -> str:
    """The parameters of a script as ``help <command>`` shows them: type, range, default, help."""
    if cls is None:
        return "parameters: none declared (the script names no parameter class)"
    lines = ["parameters (--set NAME=VALUE; the server's command options are the same):"]
    for spec in cls.specs().values():
        shown = show_value(spec.default)
        lines.append(f"  {spec.name}: {spec.describe()}{f'; default {shown}' if shown else ''}: {spec.help}"
                     + ("" if spec.option else " [setting, not a request option]"))
    return "\n".join(lines)


def _run(work: Callable[[Callable[..., None]], Any], failures: tuple[type[Exception], ...],
         refused: tuple[type[Exception], ...] = ()) -> tuple[Any, int | None]:
    """``work(progress)`` under the progress bar: its result, or the exit code of why it stopped
    (2 the command line's fault, 1 the run's, 130 Ctrl-C), said on a line of its own (after the
    bar's line, when one was drawn)."""
    drawn: list[bool] = []

    def progress(*args: Any, **kwargs: Any) -> None:
        drawn[:] = [True]
        show_progress(*args, **kwargs)

    try:
        result = work(progress)
    except refused as exc:
        code, text = 2, str(exc)
    except failures as exc:
        code, text = 1, str(exc)
    except KeyboardInterrupt:
        code, text = 130, "interrupted"
    else:
        if drawn:
            sys.stderr.write("\n")
        return result, None
    sys.stderr.write(f"{chr(10) if drawn else ''}rvs-prox: {text}\n")
    return None, code


def _main_from(script: str, source: str, sets: list[str], out: str | None) -> int:
    """``rvs-prox dem --from JOB``: a recorded DEM job run again (prox_workflows.reprocess)."""
    from ..reprocess import ReprocessError, parse_overrides, reprocess

    # a ReprocessError is the command line's fault: no such job, a parameter it refuses
    result, code = _run(lambda progress: reprocess(source, parse_overrides(sets), out, script=script, progress=progress),
                        (WorkflowError, FileNotFoundError), refused=(ReprocessError,))
    if code is not None:
        return code
    print(f"views: {result['views']}")
    for layer, path in result["files"].items():
        print(f"{layer}: {path}")
    return 0


# The campaign tools are dispatched before the script parser sees argv, so argparse would never
# mention them: the help names them here.
CAMPAIGN_HELP = """\
campaign commands (each has its own --help):
  rvs-prox batch SCRIPT --inputs GLOB [--scheduler tcp://HOST:PORT] [--workers N] [-o DIR]
                        re-run every recorded DEM job the GLOB finds on Dask (a LocalCluster
                        here by default), one task per job; up-to-date jobs are skipped
  rvs-prox mosaic-campaign --inputs GLOB -o DIR [--name NAME] [--cell M] [--tile N]
                        fuse site DEMs (*_dem.tif) into one mosaic written tile by tile:
                        DIR/NAME_dem.tif, NAME_variance.tif, NAME_count.tif (NAME: mosaic)
"""


def main(argv: list[str] | None = None) -> int:
    """``rvs-prox SCRIPT [--validate] [--set key=value] [--help]``: validate or run a script;
    ``rvs-prox batch|mosaic-campaign ...``: the campaign tools (prox_workflows.batch)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("batch", "mosaic-campaign"):  # the campaign tools (prox_workflows.batch)
        from . import batch

        return batch.main(argv)
    ap = ToolParser(prog="rvs-prox", description="Validate or run a PROX-like workflow script.",
                    formatter_class=argparse.RawDescriptionHelpFormatter, add_help=False, epilog=CAMPAIGN_HELP)
    ap.add_argument("script", nargs="?", help="script name (in prox_workflows/scripts) or path; or one of the "
                                              "campaign commands below")
    ap.add_argument("-h", "--help", action="store_true", help="show this help (and the script's parameters)")
    ap.add_argument("--validate", action="store_true", help="check the script and stop; nothing runs")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="set a parameter")
    ap.add_argument("--input", action="append", default=[], metavar="NAME=VALUE",
                    help="supply one of the script's inputs (a folder, a file: --input views=data/dem/site_views)")
    ap.add_argument("--log", help="write the run log (YAML) here")
    ap.add_argument("--from", dest="from_", metavar="JOB",
                    help="re-run a recorded DEM job (data/dem/site, or its site_views folder) with the "
                         "parameters it recorded, --set overriding them")
    ap.add_argument("-o", "--out", metavar="DIR",
                    help="with --from: the folder the products go in (default <job dir>/reprocessed)")
    args = ap.parse_args(argv)
    if not args.help and not args.script:
        ap.error("name a script to run (or batch, mosaic-campaign)")
    if args.log and not Path(args.log).absolute().parent.is_dir():  # found out before the run, not after it
        ap.error(f"--log {args.log}: no folder {Path(args.log).absolute().parent}")
    if args.help:
        text = ap.format_help()
        if args.script:
            try:
                script = load_script(args.script)
                text += f"\nscript {script['name']} ({script_path(args.script)}):\n"
                text += params_help(param_class(script)) + "\n"
                if script.get("inputs"):
                    text += "inputs (--input NAME=VALUE):\n" + "".join(
                        f"  {k}: {v}\n" for k, v in script["inputs"].items())
            except WorkflowError as exc:
                text += f"\n{exc}\n"
        print(text, end="")
        return 0
    if args.from_:
        return _main_from(args.script, args.from_, args.set, args.out)
    try:
        params = assignments(args.set)
        inputs = {k: _parse_value(v) for k, v in assignments(args.input, flag="--input", form="name=value").items()}
    except SettingError as exc:
        ap.error(exc.message)
    try:
        script = load_script(args.script)
        cls = param_class(script)
        typed: dict[str, Any] = {}
        for key, raw in params.items():
            spec = cls.specs().get(key) if cls is not None else None
            typed[key] = spec.parse(str(raw), f"--set {key}") if spec is not None else _parse_value(raw)
        if args.validate:
            validate(script, typed, list(inputs) + list(script.get("inputs") or {}))
            print(f"{script['name']}: valid ({len(script['steps'])} steps)")
            return 0
    except ScriptError as exc:  # the script's own mistakes, each with its line: --validate's verdict (1), or a
        # script the run was given that cannot run (2, as any bad input); one mistake is one line
        sys.stderr.write(f"rvs-prox: {exc.problems[0] if len(exc.problems) == 1 else exc}\n")
        return 1 if args.validate else 2
    except (WorkflowError, SettingError) as exc:  # no such script, a --set value its parameter refuses
        sys.stderr.write(f"rvs-prox: {exc}\n")
        return 2

    done, code = _run(lambda progress: run_workflow(script, typed, inputs, progress=progress),
                      (WorkflowError, FileNotFoundError, ValueError))
    if code is not None:
        return code
    ws, log = done
    text = yaml.safe_dump(log.as_dict(), sort_keys=False)
    if args.log:
        try:
            Path(args.log).write_text(text)
        except OSError as exc:
            sys.stderr.write(f"rvs-prox: cannot write the log {args.log}: {exc.strerror or exc}\n")
            return 2
    print(text, end="")
    for key, value in ws.items():
        if isinstance(value, str | int | float | Path):
            print(f"{key}: {value}")
        elif isinstance(value, dict) and all(isinstance(v, str | Path) for v in value.values()):
            for k, v in value.items():
                print(f"{key}.{k}: {v}")
    return 0


def _parse_value(raw: str) -> Any:
    try:
        return yaml.safe_load(raw)
    except yaml.YAMLError:
        return raw
