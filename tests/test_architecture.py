"""The architecture is checked, not only described: the import contracts of pyproject.toml
([tool.importlinter]: tools > rvs_truth > rvs_server > prox_workflows | drivers > rvs_params, no import cycle
between sibling packages or modules) and ruff's rules, complexity among them, hold on the tree."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _run(*cmd: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)


def test_the_layers_hold_and_no_package_has_an_import_cycle() -> None:
    out = _run(str(BIN / "lint-imports"), "--no-cache")
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
    assert "2 kept, 0 broken" in out.stdout, out.stdout[-2000:]


def test_ruff_is_clean_with_the_complexity_limit() -> None:
    out = _run(sys.executable, "-m", "ruff", "check", "--no-cache", ".")
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
