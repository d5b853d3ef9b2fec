"""Navigation's layout: no import cycle through it, and the rover's backends are found by the
registry alone (a new backend is its module and the package's import line)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _module(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _runtime_nodes(tree: ast.AST) -> list[ast.AST]:
    """Every node but those under ``if TYPE_CHECKING:`` (annotations only: no import runs)."""
    out: list[ast.AST] = []
    todo = [tree]
    while todo:
        node = todo.pop()
        out.append(node)
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            todo.extend(node.orelse)
            continue
        todo.extend(ast.iter_child_nodes(node))
    return out


def _imports(path: Path) -> set[str]:
    """The modules ``path`` imports when it runs, anywhere in it (a function's deferred import
    too: a cycle through one still ties the two modules together)."""
    here = _module(path).split(".")
    package = here if path.name == "__init__.py" else here[:-1]
    out: set[str] = set()
    for node in _runtime_nodes(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = package[: len(package) - node.level + 1] if node.level else []
            mod = ".".join(base + ([node.module] if node.module else []))
            out.add(mod)
            out.update(f"{mod}.{a.name}" for a in node.names)  # from . import see
    return out


def _graph(packages: tuple[str, ...]) -> dict[str, set[str]]:
    files = [p for pkg in packages for p in (ROOT / pkg).rglob("*.py")]
    modules = {_module(p): p for p in files}
    return {name: {m for m in _imports(path) if m in modules and m != name} for name, path in modules.items()}


def _cycle_through(graph: dict[str, set[str]], start: str) -> list[str] | None:
    """A chain of imports from ``start`` back to it, if there is one."""
    stack, seen = [(start, [start])], set()
    while stack:
        node, path = stack.pop()
        for nxt in graph.get(node, ()):
            if nxt == start:
                return path + [start]
            if nxt not in seen:
                seen.add(nxt)
                stack.append((nxt, path + [nxt]))
    return None


def test_no_import_cycle_runs_through_navigation_or_the_rover() -> None:
    graph = _graph(("rvs_server", "drivers"))
    ours = [m for m in graph if m.startswith(("rvs_server.navigation", "drivers.rover"))]
    ours.append("rvs_server.commands.navigation")
    assert len(ours) >= 12
    cycles = {m: c for m in ours if (c := _cycle_through(graph, m)) is not None}
    assert not cycles, cycles
    # and the package holds the mission, not the command module: the handlers stay thin
    assert "rvs_server.navigation.mission" in graph["rvs_server.commands.navigation"]
    assert not any(m.startswith("rvs_server.navigation") and "rvs_server.commands.navigation" in deps
                   for m, deps in graph.items())


def test_a_rover_backend_is_its_module_and_one_import_line() -> None:
    """The registry composes the settings and builds the backend by name: nothing else in the
    server names a rover backend."""
    named = [p.relative_to(ROOT) for p in (ROOT / "rvs_server").rglob("*.py")
             if "GncRover" in p.read_text() or "SimRover" in p.read_text()]
    assert not named, named
    init = (ROOT / "drivers" / "rover" / "__init__.py").read_text()
    assert "from . import gnc, sim  # noqa: F401 - registers the backends" in init
