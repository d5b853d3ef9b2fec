"""What keeps the event loop answering while heavy jobs run: every numba kernel releases the GIL
(``nogil=True``, declared once by :func:`rvs_params.jit.jit`, the one caller of numba's compiler), so a job thread inside one does not hold status, break and the other
connections up; and the start's heap is frozen out of the cyclic collector's full walks while
the server runs, and given back when it stops. The latencies themselves are measured by
``python -m tools.bench.server``, not asserted here (they depend on the machine's load)."""

from __future__ import annotations

import ast
import gc
import importlib
from pathlib import Path
from typing import Any

import pytest
from support.server import wait_for

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("prox_workflows", "rvs_server", "rvs_params", "drivers")
JIT_NAMES = {"njit", "jit", "generated_jit"}


def _jit_sites() -> list[tuple[Path, ast.AST, bool]]:
    """Every place the server's packages call numba's compiler: a call of ``numba.njit(...)``
    (or ``jit``, ``njit`` imported bare from numba) or a bare ``@numba.njit`` decorator; and
    whether it passes ``nogil=True``."""
    sites = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            text = path.read_text()
            if "numba" not in text:
                continue
            tree = ast.parse(text)
            bare = {a.asname or a.name for node in ast.walk(tree)
                    if isinstance(node, ast.ImportFrom) and node.module == "numba"
                    for a in node.names if a.name in JIT_NAMES}
            for node in ast.walk(tree):
                if isinstance(node, ast.Call) and _is_jit(node.func, bare):
                    nogil = any(k.arg == "nogil" and isinstance(k.value, ast.Constant) and k.value.value is True
                                for k in node.keywords)
                    sites.append((path, node, nogil))
                elif isinstance(node, ast.FunctionDef):
                    sites.extend((path, d, False) for d in node.decorator_list if _is_jit(d, bare))
    return sites


def _is_jit(node: ast.AST, bare: set[str]) -> bool:
    if isinstance(node, ast.Attribute):
        return node.attr in JIT_NAMES and isinstance(node.value, ast.Name) and node.value.id == "numba"
    return isinstance(node, ast.Name) and node.id in bare


def test_every_numba_kernel_is_declared_nogil() -> None:
    sites = _jit_sites()
    assert sites, "the scan no longer finds numba's compiler (renamed decorator?)"
    callers = sorted({str(p.relative_to(ROOT)) for p, _, _ in sites})
    assert callers == ["rvs_params/jit.py"], f"kernels compile through rvs_params.jit.jit, not numba directly: {callers}"
    missing = [f"{p.relative_to(ROOT)}:{n.lineno}" for p, n, nogil in sites if not nogil]
    assert not missing, f"numba kernels without nogil=True (a job inside one holds the event loop up): {missing}"


def _dispatchers() -> dict[str, Any]:
    """The compiled kernels themselves, module-level ones and those made on first use."""
    dispatcher = pytest.importorskip("numba.core.dispatcher").Dispatcher
    from prox_workflows.algorithms import astar, dem_import

    found: dict[str, Any] = {}
    for module in ("prox_workflows.algorithms._replan_kernels", "prox_workflows.algorithms._dem2hazard_kernel"):
        mod = importlib.import_module(module)
        found.update({f"{module}.{name}": v for name, v in vars(mod).items() if isinstance(v, dispatcher)})
    kernels = dem_import._kernels()
    assert kernels is not None
    found.update({f"dem_import.{name}": v for name, v in kernels.items()})
    found["astar"] = astar._compiled_kernel()
    return found


def test_compiled_kernels_release_the_gil() -> None:
    kernels = _dispatchers()
    assert len(kernels) >= 8
    held = sorted(name for name, d in kernels.items() if d.targetoptions.get("nogil") is not True)
    assert not held, f"compiled without nogil: {held}"


def test_start_heap_frozen_while_serving_and_given_back(server_factory: Any) -> None:
    gc.unfreeze()  # whatever another test left
    srv = server_factory(["server.warm_up=true"])
    assert wait_for(lambda: gc.get_freeze_count() > 0, timeout=120)  # after the kernels' warm-up
    assert srv.client().request("version").status == "OK"
    srv.stop()
    assert gc.get_freeze_count() == 0  # a stopped server's objects can be collected again
