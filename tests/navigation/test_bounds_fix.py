"""The see loop's bounds map (the chooser's) moves with a localisation fix as its rolling map
does: the frames placed since the last fix with the pose the fix corrects move by the fix, the
earlier ones stay. And a navigate's mission is handed to what watches the server on its bus
(the scale bench reads the loop's timings and maps through it)."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from prox_workflows.algorithms.bounds_map import BoundsMap
from rvs_server.navigation.see_strategy import SeeStrategy


def _rock(x: float, y: float) -> np.ndarray:
    gx, gy = np.meshgrid(np.arange(x - 0.6, x + 0.6, 0.01) + 0.005, np.arange(y - 0.6, y + 0.6, 0.01) + 0.005)
    gx, gy = gx.ravel(), gy.ravel()
    return np.column_stack([gx, gy, np.where((np.abs(gx - x) < 0.1) & (np.abs(gy - y) < 0.1), 0.2, 0.0)])


class _Rolling:
    """The rolling map's part in a fix: its frame count, its frames since, and the moves it took."""

    def __init__(self) -> None:
        self.frames, self.moves = 0, []
        self.geometry = None

    def since(self, first: int) -> np.ndarray:
        return np.zeros((1, 1))

    def move(self, pivot: Any, dx: float, dy: float, dyaw: float, since: int) -> None:
        self.moves.append((pivot, dx, dy, dyaw, since))


class _Localiser:
    """Map matching that finds the fixes it is given, one per call."""

    uses_map, grown = True, 0.0

    def __init__(self, fixes: list[tuple[float, float, float]]) -> None:
        self.fixes = fixes

    def after_drive(self, job: Any, driven: np.ndarray) -> float:
        return 3.0

    def while_seeing(self, job: Any, leg: int, dem: Any, geometry: Any, standing: bool = False) -> Any:
        return self.fixes.pop(0)


def _upper(m: BoundsMap, x: float, y: float) -> float:
    _, upper, _ = m.window(x - 0.001, y - 0.001, x + 0.001, y + 0.001)
    return float(upper[0, 0])


def test_a_map_fix_moves_the_bounds_maps_rock_by_the_fix_and_only_the_frames_since_the_last() -> None:
    bounds = BoundsMap.around((0.0, 0.0), 4.6, 0.25)
    rolling = _Rolling()
    s = SeeStrategy.__new__(SeeStrategy)  # the strategy's state a fix reads, without a mission
    s.localiser = _Localiser([(0.25, -0.1, 0.0), (0.0, 0.5, 0.0)])
    s.driver = SimpleNamespace(map=rolling, bounds=bounds)
    s.app = SimpleNamespace(pose=SimpleNamespace(x=0.0, y=0.0, heading=0.0))
    s.mission = SimpleNamespace(goal=(50.0, 0.0))
    s.p = SimpleNamespace(localise_every=2.0)
    s.cfg = SimpleNamespace(tolerance=0.3)
    s.job, s.since_fix, s.fixed_at, s.bounds_fixed_at = None, 0.0, 0, 0
    bounds.fuse(_rock(1.5, 0.5), 0.003, np.array([0.0, 0.0, 1.2]))  # placed with the drifted pose
    assert _upper(bounds, 1.5, 0.5) > 0.19
    s.localise(1, np.zeros((2, 2)))
    assert rolling.moves == [((0.0, 0.0), 0.25, -0.1, 0.0, 0)]
    assert _upper(bounds, 1.75, 0.4) > 0.19  # the rock's top moved by the fix
    assert not _upper(bounds, 1.5 - 0.14, 0.5) > 0.05  # and not still where the drifted pose put it
    # a second rock after the fix; the next fix moves it, not the first
    bounds.fuse(_rock(-1.5, -1.0), 0.003, np.array([0.0, 0.0, 1.2]))
    s.localise(2, np.zeros((2, 2)))
    assert _upper(bounds, -1.5, -0.5) > 0.19 and not _upper(bounds, -1.5, -1.0 - 0.14) > 0.05
    assert _upper(bounds, 1.75, 0.4) > 0.19 and not _upper(bounds, 1.75, 0.9) > 0.05


def test_a_navigate_hands_its_mission_to_the_bus(tmp_path: Path) -> None:
    from tools.bench.navigate import scene_server

    seen: list[Any] = []
    srv = scene_server(tmp_path, "marsyard")
    try:
        srv.app.bus.subscribe(lambda item: seen.append(item.data["mission"]) if item.kind == "mission" else None)
        r = srv.request("navigate -start 0,0,0 -goal 0.1,0 -auto -loop see -name t")
        assert r.status == "OK", r.fields
    finally:
        srv.stop()
    assert len(seen) == 1
    mission = seen[0]
    assert mission.goal == (0.1, 0.0) and mission.strategy.driver.bounds is not None
    g = mission.strategy.driver.bounds.geometry
    assert g.width == g.height and math.isclose(g.xmin % 0.25, 0.0, abs_tol=1e-9)
