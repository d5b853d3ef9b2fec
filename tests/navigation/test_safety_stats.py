"""The pose-level safety statistics (rvs_truth.stats): the exact binomial bound a false-safe rate
is stated with, and the correlation length that says how many judged poses make one trial."""

import math

import numpy as np
import pytest
from scipy.stats import binom
from support.marks import long_test

from prox_workflows.algorithms.bounds_map import BoundsParams
from rvs_truth.stats import clopper_pearson_upper, events_per_distance_upper, poses_per_trial


@pytest.mark.parametrize("n", [1, 30, 1000, 20000])
def test_zero_failures_bound_is_the_closed_form(n: int) -> None:
    assert clopper_pearson_upper(0, n) == pytest.approx(1 - 0.05 ** (1 / n), rel=1e-9)
    # the two-sided 95 % interval's upper end is the one-sided 97.5 % bound
    assert clopper_pearson_upper(0, n, 0.975) == pytest.approx(1 - 0.025 ** (1 / n), rel=1e-9)


def test_rule_of_three() -> None:
    # 30 clean missions say "at most 10 %"; 20,000 clean poses about 1.5e-4
    assert clopper_pearson_upper(0, 30) == pytest.approx(0.0950, abs=1e-4)
    assert clopper_pearson_upper(0, 20000) == pytest.approx(3 / 20000, rel=0.01)


@pytest.mark.parametrize("k,n", [(1, 10), (3, 200), (12, 20000)])
def test_bound_is_where_k_or_fewer_failures_become_5_percent_likely(k: int, n: int) -> None:
    p = clopper_pearson_upper(k, n)
    assert binom.cdf(k, n, p) == pytest.approx(0.05, abs=1e-9)
    assert p > k / n
    if (k, n) == (1, 10):
        assert p == pytest.approx(0.3942, abs=1e-4)  # the tabulated exact one-sided bound


def test_bad_counts_are_refused() -> None:
    with pytest.raises(ValueError):
        clopper_pearson_upper(5, 3)
    with pytest.raises(ValueError):
        clopper_pearson_upper(0, 0)
    assert clopper_pearson_upper(4, 4) == 1.0


def blocks(rng: np.random.Generator, m: int, count: int, length: int) -> list[np.ndarray]:
    """Paths of 0/1 verdicts constant over runs of ``m`` poses, each run drawn at random."""
    return [np.repeat(rng.integers(0, 2, length // m), m).astype(float) for _ in range(count)]


def test_poses_per_trial_is_the_run_length_of_a_block_process() -> None:
    rng = np.random.default_rng(7)
    assert poses_per_trial(blocks(rng, 1, 200, 500)) == pytest.approx(1.0, abs=0.15)
    assert poses_per_trial(blocks(rng, 5, 200, 500)) == pytest.approx(5.0, rel=0.1)
    assert poses_per_trial(blocks(rng, 20, 400, 500)) == pytest.approx(20.0, rel=0.1)


def test_unjudged_poses_break_pairs_but_not_the_measure() -> None:
    rng = np.random.default_rng(8)
    paths = blocks(rng, 10, 400, 500)
    for p in paths:
        p[rng.random(len(p)) < 0.2] = np.nan
    assert poses_per_trial(paths) == pytest.approx(10.0, rel=0.1)
    assert math.isnan(poses_per_trial([np.ones(50), np.array([1.0, np.nan])]))


def test_events_per_distance() -> None:
    # 20,000 clean poses 2 cm apart: about 3 / 400 m whatever the correlation length
    for per_trial in (1.0, 10.0, 25.0):
        e = events_per_distance_upper(0, 20000, per_trial, 0.02)
        assert e == pytest.approx(100 * 3 / (20000 * 0.02), rel=0.02)
    # one event in 20,000 poses, one trial per 25 poses: the bound over 800 trials, 200 trials per 100 m
    assert events_per_distance_upper(1, 20000, 25.0, 0.02) == pytest.approx(clopper_pearson_upper(1, 800) * 200)


def test_the_stated_risk_sums_a_scenes_looks_before_bounding_the_rate() -> None:
    """The bound is on the scene's pooled poses (1 false safe in 4,100), not each look's, and the
    share kept is weighed by each look's truly safe poses."""
    from tools.bench.chance import risk_table

    rows = [{"scene": "marsyard", "judged": 2000, "false_safe": 0, "kept": 0.8, "of": 1500},
            {"scene": "marsyard", "judged": 2100, "false_safe": 1, "kept": 0.9, "of": 500},
            {"scene": "dense", "judged": 1900, "false_safe": 0, "kept": 0.5, "of": 1000}]
    marsyard, dense = risk_table(rows)[2:]
    assert marsyard.split(" | ")[1:4] == ["2", "4,100", "1"]
    assert f"{clopper_pearson_upper(1, 4100):.1e}" in marsyard and "82.5 %" in marsyard
    assert f"{1 - 0.05 ** (1 / 1900):.1e}" in dense and "50.0 %" in dense


def test_the_stated_risk_gives_the_share_kept_of_every_truly_safe_pose_judged_or_not() -> None:
    """A model that leaves poses unknown judges fewer: its share kept of those it judges rises while
    it keeps fewer poses. The table gives both: 1,300 kept of 2,000 truly safe poses is 65 %,
    whatever share of them each model judged."""
    from tools.bench.chance import risk_table

    rows = [{"scene": "hirise", "judged": 1500, "false_safe": 0, "kept": 0.8, "of": 1000, "safe_n": 800,
             "truly_safe": 1200},
            {"scene": "hirise", "judged": 700, "false_safe": 0, "kept": 0.833, "of": 600, "safe_n": 500,
             "truly_safe": 800}]
    (hirise,) = risk_table(rows)[2:]
    cols = hirise.split(" | ")
    assert cols[-2] == "81.2 %" and cols[-1] == "65.0 % |"


def test_the_stated_risk_tabulates_each_against_set_on_its_own(monkeypatch: pytest.MonkeyPatch,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """``--against`` given twice: each set is a model of its own, judged on the same looks, and gets
    its own table (a look's row carries one count per set, in the order given)."""
    import tools.bench.chance as bench

    asked = {}

    def looks(scenes, looks, seeds, cell, samples, jobs, against, params):  # noqa: ANN001, ANN202
        asked["against"], asked["params"] = against, params
        miss = {"pose": [1.0, 0.0, 0.0], "truth_excess": {"belly": 0.003}, "nominal_excess": {}, "p_any": 2e-4}
        return [{"scene": "dense", "judged": 1000, "false_safe": 2, "kept": 0.6, "of": 500, "safe_n": 300,
                 "truly_safe": 600, "misses": [miss, miss],
                 "against": [{"judged": 1000, "false_safe": 1, "kept": 0.5, "of": 500, "safe_n": 250, "misses": [miss]},
                             {"judged": 900, "false_safe": 0, "kept": 0.4, "of": 450, "safe_n": 180, "misses": []}]}]

    monkeypatch.setattr(bench, "risk", looks)
    bench.main(["--risk", "--scenes", "dense", "--against", "epsilon=1e-4", "--against", "edge_sigma=0.3",
                "samples=32"])
    assert asked["against"] == [{"epsilon": 1e-4}, {"edge_sigma": 0.3, "samples": 32}]
    assert isinstance(asked["against"][1]["samples"], int)
    assert asked["params"] == BoundsParams()  # the map's own parameters unless --bounds says otherwise
    out = capsys.readouterr().out
    declared, first, second = out.split("the same with ")[0], *out.split("the same with ")[1:]
    assert "| dense | 1 | 1,000 | 2 |" in declared and "60.0 % | 50.0 % |" in declared
    assert first.startswith("epsilon=1e-4\n") and "| dense | 1 | 1,000 | 1 |" in first and "50.0 % | 41.7 % |" in first
    assert second.startswith("edge_sigma=0.3 samples=32\n") and "| dense | 1 | 900 | 0 |" in second
    assert "40.0 % | 30.0 % |" in second


def test_the_stated_risk_fuses_its_looks_with_the_bounds_map_s_parameters_given(
        monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """``--bounds`` changes the map every look is fused into (a run of its own, unlike ``--against``),
    typed by BoundsParams' declaration; a key it does not declare is one clear ERROR line."""
    import tools.bench.chance as bench

    asked = {}

    def looks(scenes, looks, seeds, cell, samples, jobs, against, params):  # noqa: ANN001, ANN202
        asked["params"] = params
        return [{"scene": "dense", "judged": 10, "false_safe": 0, "kept": 0.5, "of": 4, "safe_n": 2, "truly_safe": 5}]

    monkeypatch.setattr(bench, "risk", looks)
    bench.main(["--risk", "--scenes", "dense", "--bounds", "stereo_first=true", "k=3"])
    assert asked["params"].stereo_first is True and asked["params"].k == 3.0
    assert "the map's stereo_first=true k=3" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="ERROR: --bounds stereo_frist: unknown key; known: cell, k"):
        bench.main(["--risk", "--bounds", "stereo_frist=true"])


def test_the_stated_risk_refuses_a_setting_the_check_does_not_declare() -> None:
    """A misspelt name is one clear ERROR line before any look is fused, not a model silently
    judged as the declared one."""
    import subprocess
    import sys

    for word in ("epsilom=1e-4", "epsilon=small"):
        run = subprocess.run([sys.executable, "-m", "tools.bench.chance", "--risk", "--against", word],
                             capture_output=True, text=True, timeout=120)
        assert run.returncode != 0
        (line,) = run.stderr.strip().splitlines()
        assert line.startswith("ERROR: --against takes NAME=VALUE, NAME one of ")
        assert "epsilon" in line and f"got '{word}'" in line and run.stdout == ""


@long_test
def test_the_rock_top_splits_its_worst_cells_into_the_mean_read_low_and_the_relief_missed() -> None:
    """``--rock-top`` on one look of dense: an ``--against`` set is judged on the same map (only
    what it changes moves: rock_sigma halved halves the declared sigma, the errors stay), and the
    worst 1 % of each band's cells split their error into the cell's mean read low and the relief
    the top misses, which sum to the error of those cells (at least the band's p99)."""
    from tools.bench.chance import rock_top

    rows = rock_top(["dense"], "approach+hazcam", 0.025, [2], 1, [{"rock_sigma": 0.1}])
    declared = [r for r in rows if r["setting"] == 0]
    halved = [r for r in rows if r["setting"] == 1]
    assert declared and [r["band"] for r in declared] == [r["band"] for r in halved]
    for a, b in zip(declared, halved, strict=True):
        assert a["cells"] == b["cells"] and a["q999"] == b["q999"]
        assert b["declared"] == pytest.approx(a["declared"] / 2, rel=1e-6)
        split = a["worst_mean"] + a["worst_relief"]
        assert a["q99"] <= split <= a["max"] + 1e-9
    # the 2-4 cm band is the biggest: its worst cells are read low by both, each a few millimetres
    low = declared[0]
    assert low["band"][0] == pytest.approx(0.02) and low["cells"] > 1000
    assert 0.002 < low["worst_mean"] < 0.03 and 0.002 < low["worst_relief"] < 0.03
