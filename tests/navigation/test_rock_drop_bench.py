"""The rock-drop bench's summary (tools.bench.rock_drop): only trials where a rock lay on the
ground are judged, so a refused drop can neither pass nor fail."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from tools.bench.rock_drop import after_drop, dropped, table


def _row(i: int, **fields: Any) -> dict[str, Any]:
    return {"scene": "marsyard", "trial": i, "start": (0.0, 0.0), "goal": (10.0, 0.0), "after": 1.5,
            "radius": 0.2, "height": 0.2, "wall_s": 100.0, "status": "OK", **fields}


def _judged(i: int, clearance: float, events: list[dict[str, Any]]) -> dict[str, Any]:
    return _row(i, end="passed" if clearance > 0 else "stood", drop_pose=(1.5, 0.0, 0.0), ahead=2.0, dir=0.0,
                rock=(3.5, 0.0, 0.2), blocks_goal=True, reaction="stop", reaction_s=1.2, stops=1, sections=0,
                stop_reasons=["recheck"], clearance=clearance, events=events, poses_checked=200,
                passed=clearance > 0 and not events)


def test_a_refused_rock_is_reported_apart_and_left_out_of_the_pass_count(capsys: pytest.CaptureFixture[str]) -> None:
    refused = _row(2, end="rock refused", refused="sim add-rock: the rock would be off the terrain")
    never = _row(3, end="job ended")
    rows = [_judged(0, 0.31, []),
            _judged(1, -0.04, [{"kind": "belly", "excess": 0.021, "x": 3.4, "y": 0.0, "at_rock": True}]),
            refused, never]
    assert [dropped(r) for r in rows] == [True, True, False, False]
    table(rows)
    out = capsys.readouterr().out
    assert "rock refused: sim add-rock: the rock would be off the terrain" in out
    summary = out.strip().splitlines()[-1]
    assert summary.startswith("marsyard: 1/2 trials passed"), summary
    assert "1/2 of those with the rock on the straight way" in summary
    assert "1 ended before the drop; 1 rock refused (not run)" in summary


def test_a_trial_is_judged_on_its_track_from_the_drop_on() -> None:
    # a turn at the start over ground the rock later covered, then a drive out and back past it:
    # the rock came when the rover stood at (2, 0) heading 180, so the turn at the start is not judged
    start_turn = [(0.0, 0.0, h) for h in (0.0, 45.0, 90.0)]
    out = [(x, 0.0, 0.0) for x in (0.5, 1.0, 1.5, 2.0)]
    back = [(2.0, 0.0, 90.0), (2.0, 0.0, 180.0), (1.5, 0.0, 180.0), (1.0, 0.1, 180.0)]
    poses = np.array(start_turn + out + back)
    judged = after_drop(poses, (2.0, 0.0, 180.0))
    np.testing.assert_array_equal(judged, poses[8:])
    # a drop pose the track never held (a rounded pose off the track): the whole track
    assert len(after_drop(poses, (5.0, 5.0, 0.0))) == len(poses)
