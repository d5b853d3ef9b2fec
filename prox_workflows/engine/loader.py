"""Loading scripts: YAML with the line of every mapping kept (validation names the line of each
mistake), ``include:`` inlined."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from .errors import ScriptError, WorkflowError

SCRIPTS_DIR = Path(__file__).resolve().parents[1] / "scripts"


class _LineLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc]
    """Keeps the line of every mapping, so validation can say where a mistake is. On libyaml where
    PyYAML has it: every server and CLI start loads the scripts, 8x faster so."""


def _construct_mapping(loader: _LineLoader, node: yaml.MappingNode) -> dict[str, Any]:
    mapping = Lined(loader.construct_mapping(node, deep=True))
    mapping.line = node.start_mark.line + 1
    return mapping


class Lined(dict):  # noqa: FURB189 - a dict that remembers its line
    line: int = 0
    source: str = ""


_LineLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def script_path(name_or_path: str | Path) -> Path:
    path = Path(name_or_path)
    if not path.suffix:
        path = SCRIPTS_DIR / f"{path.name}.yaml"
    return path


def load_script(name_or_path: str | Path) -> dict[str, Any]:
    """A script with its ``include:`` steps inlined; each step remembers its file and line."""
    return _load(script_path(name_or_path), [])


def _load(path: Path, stack: list[Path]) -> dict[str, Any]:
    if not path.is_file():
        raise WorkflowError(f"no workflow script {path.stem} (looked at {path})")
    try:
        script = yaml.load(path.read_text(), Loader=_LineLoader) or {}  # noqa: S506 - a SafeLoader
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path.name}:{mark.line + 1}" if mark is not None else path.name
        problem = getattr(exc, "problem", None) or " ".join(str(exc).split())
        raise ScriptError(path.name, [f"{where}: not YAML ({problem}); fix the syntax"]) from None
    if not isinstance(script, dict) or not isinstance(script.get("steps"), list):
        raise ScriptError(path.name, [f"{path.name}:1: a script needs 'steps:', a list of steps; add one"])
    script.setdefault("name", path.stem)
    steps: list[Any] = []
    for spec in script["steps"]:
        if isinstance(spec, Lined):
            spec.source = path.name
        if isinstance(spec, dict) and "include" in spec:
            inner = script_path(spec["include"])
            if inner in stack or inner == path:
                raise ScriptError(path.name, [f"{path.name}:{getattr(spec, 'line', 0)}: include of "
                                              f"{inner.stem} loops back to itself; remove it"])
            included = _load(inner, [*stack, path])
            steps.extend(included["steps"])
            for key in ("inputs", "outputs"):
                if key in included and key not in script:
                    script[key] = included[key]
            continue
        steps.append(spec)
    script["steps"] = steps
    script["_file"] = path.name
    return script
