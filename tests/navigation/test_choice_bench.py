"""tools.bench.choice through its command line: a dumped choice is timed on the reference path and
the fast one, which must agree, and a missing dump is a clear error."""

from __future__ import annotations

import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
from support.marks import long_test

from drivers.sim.world import World
from prox_workflows.algorithms.bounds_map import BoundsMap
from prox_workflows.algorithms.candidates import CandidateParams
from prox_workflows.algorithms.chance import ChanceParams
from tools.bench.bounds import tof_frame

ROOT = Path(__file__).resolve().parents[2]


@long_test  # the bench times both paths in a subprocess, 15-30 s
def test_a_dumped_choice_is_timed_on_both_paths_which_agree(tmp_path: Path) -> None:
    world = World.from_scene("hirise", seed=1)
    rng = np.random.default_rng(0)
    m = BoundsMap.covering([[-1.0, -3.0], [4.0, 3.0]], 1.0)
    for pan in (-40.0, 0.0):
        f = tof_frame(world, rng, pan)
        m.fuse(f["points"], f["sigma"], f["origin"], *f["args"], **f["kwargs"])
    # the ground round the mast's foot, which no tilt shows, as the see loop's set-down takes it
    z = float(world.true_dem(0.05, (-0.1, -0.1, 0.1, 0.1)).mean())
    m.set_down((0.0, 0.0), 1.3, z)
    m.stood((0.0, 0.0, 0.0), z, world.body)
    m.whole()  # the whole bounds as a choice before left them
    f = tof_frame(world, rng, 40.0)
    m.fuse(f["points"], f["sigma"], f["origin"], *f["args"], **f["kwargs"])
    entry = {"bounds": m, "pose": (0.0, 0.0, 0.0), "goal": (4.0, 1.0), "body": world.body, "how": "chance",
             "params": CandidateParams(), "chance": ChanceParams(), "section": np.zeros((0, 3)), "status": "",
             "scene": "hirise", "mission": 0, "choice": 0, "frame": tof_frame(world, rng, 0.0)}
    from rvs_server.navigation.sections import choose_from

    choice, _ = choose_from(m, entry["pose"], entry["goal"], world.body, "chance", CandidateParams(), ChanceParams())
    assert choice.status == "drive"
    entry["section"] = choice.poses
    with open(tmp_path / "choice000.pkl", "wb") as fh:
        pickle.dump(entry, fh)
    run = subprocess.run([sys.executable, "-m", "tools.bench.choice", "--maps", str(tmp_path), "--rounds", "1"],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    assert "1 choices" in lines[0] and "verdicts identical on both paths" in lines[0]
    rows = {line.split()[0]: line.split() for line in lines[2:]}
    assert set(rows) == {"window", "choice", "cycle"}
    for r in rows.values():
        rp50, rp95, fp50, fp95, ratio, rcpu, fcpu, cratio = (float(v) for v in r[1:] if v != "/")
        assert rp50 > 0 and rp95 >= rp50 and rcpu > 0  # the reference path is timed
        # the fast path may print 0.0 where its cache answers in microseconds (the window row)
        assert fp95 >= fp50 >= 0 and fcpu >= 0 and ratio >= 0 and cratio >= 0


def test_no_dump_is_a_clear_error(tmp_path: Path) -> None:
    run = subprocess.run([sys.executable, "-m", "tools.bench.choice", "--maps", str(tmp_path)], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2
    assert f"--maps: no choice*.pkl under {tmp_path}" in run.stderr
