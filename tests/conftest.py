"""The fixtures every test may ask for: a real server on a real TCP port (``server_factory``,
``server``), a line client to it (``client``) and simulated time for its monitors (``sim_time``).
What they are built on lives in ``tests/support``."""

from __future__ import annotations

import os
import subprocess
import sys

# Bytecode is cached for the suite even where the environment says not to (PYTHONDONTWRITEBYTECODE,
# as on this project's CI machines): each of the workers, and every CLI and server the tests start, imports
# about 200 of the project's modules, and without the cache each recompiles them and re-rewrites
# the tests' asserts, 11 s of CPU a worker before its first test.
sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)

from collections.abc import Iterator  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import pytest  # noqa: E402
from hypothesis import HealthCheck, settings  # noqa: E402
from support.server import LineClient, ServerThread  # noqa: E402
from support.simtime import SimTime  # noqa: E402

# The numba kernels a fresh clone has never compiled, compiled once, by two processes side by side,
# before the workers start: each worker would otherwise compile every kernel its tests meet (some
# 30 s of CPU a worker on a fresh clone; once cached, this costs the 2 s of loading them).
# The two groups take about as long each (the vehicle check's kernel alone is a third of the whole).
KERNELS = (("prox_workflows.algorithms.vehicle", "drivers.sim.raycast", "prox_workflows.algorithms.bounds_map"),
           ("prox_workflows.algorithms.dem_import", "prox_workflows.algorithms.replan",
            "prox_workflows.algorithms.dem2hazard", "prox_workflows.algorithms.planner"))


def pytest_configure(config: pytest.Config) -> None:
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return  # a worker, or a run without workers: the kernels compile where first used
    code = "import importlib, sys\nfor m in sys.argv[1:]: importlib.import_module(m).warm_up()"
    warming = [subprocess.Popen([sys.executable, "-c", code, *group], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL) for group in KERNELS]
    for proc in warming:
        proc.wait()  # a kernel that fails to compile here fails in the test that uses it, saying why


# Hypothesis times its examples (a 200 ms deadline, the too_slow health check): that is the
# machine's speed, which no test may depend on. Tests that set their own settings keep them.
settings.register_profile("rvs", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("rvs")


@pytest.fixture
def server_factory(tmp_path: Path) -> Iterator[Any]:
    servers: list[ServerThread] = []

    def make(overrides: list[str] | None = None, data: Path | None = None, **kw: Any) -> ServerThread:
        srv = ServerThread(data or tmp_path / f"data{len(servers)}", overrides, **kw).start()
        servers.append(srv)
        return srv

    yield make
    for srv in servers:
        srv.stop()


@pytest.fixture
def server(server_factory: Any) -> ServerThread:
    return server_factory()


@pytest.fixture
def client(server: ServerThread) -> Iterator[LineClient]:
    c = server.client()
    yield c
    c.close()


@pytest.fixture
def sim_time(monkeypatch: pytest.MonkeyPatch) -> Iterator[Any]:
    """``sim_time(app, frame, on_frame)``: run a server's monitors in simulated time (tests/support/simtime.py)."""
    made: list[SimTime] = []

    def make(app: Any, frame: float, on_frame: Any = None) -> SimTime:
        made.append(SimTime(monkeypatch, app, frame, on_frame))
        return made[-1]

    yield make
    for sim in made:
        sim.close()
