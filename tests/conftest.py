"""The fixtures every test may ask for: a real server on a real TCP port (``server_factory``,
``server``), a line client to it (``client``) and simulated time for its monitors (``sim_time``).
What they are built on lives in ``tests/support``."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, settings
from support.server import LineClient, ServerThread
from support.simtime import SimTime

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
