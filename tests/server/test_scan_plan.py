"""The scan planned for the hardware: the D46's move times, the view order, the limit, and a
dem-full-tof taken in that order with the views processed while the PTU moves (simulated time)."""

from __future__ import annotations

import csv
import itertools

import numpy as np
import pytest
import yaml
from support.marks import long_test

from drivers.ptu.protocol import pos_to_deg
from prox_workflows.algorithms.ptu_positions import grid, path_time, plan, scan_limit
from prox_workflows.grid import read_geotiff
from prox_workflows.steps.scan import get_ptu_positions
from rvs_params.motion import Profile, trapezoid_time

FOV = (43.6, 34.6)
LIMITS = (-158.9, 158.9, -46.6, 31.1)
RES = 185.1428


def d46(speed: float = 1000, acceleration: float = 2000, base: float = 1000) -> dict[str, dict[str, float]]:
    """The D46's motion in degrees from positions/s (its defaults: 1000, 2000, base 1000)."""
    axis = {"speed": pos_to_deg(speed, RES), "acceleration": pos_to_deg(acceleration, RES),
            "base": pos_to_deg(base, RES)}
    return {"pan": axis, "tilt": dict(axis)}


def test_the_d46_move_time_by_hand() -> None:
    # within the base speed: no ramp, distance / speed
    assert trapezoid_time(583, 1000, 2000, base=1000) == pytest.approx(0.583)
    # above it: ramps from 1000 to 2000 at 2000/s^2 (0.5 s, 750 positions each), cruise for the rest
    assert trapezoid_time(6152, 2000, 2000, base=1000) == pytest.approx(0.5 + 0.5 + (6152 - 1500) / 2000)
    # too short to reach 2000: peak^2 = 1000^2 + 2000 * 1000, up and down from 1000
    assert trapezoid_time(1000, 2000, 2000, base=1000) == pytest.approx(2 * (np.sqrt(3e6) - 1000) / 2000)
    # base 0 (the ramps from rest): what the emulator did before the base speed
    assert trapezoid_time(583, 1000, 2000) == pytest.approx(583 / 1000 + 1000 / 2000)
    # the emulator's profile takes exactly that long and ends at rest on the target
    prof = Profile.start(0.0, 0.0, 0.0, 6152, 2000, 2000, 1000)
    assert prof.end == pytest.approx(3.326)
    assert prof.at(0.0 + 1e-9)[1] == pytest.approx(1000, abs=1e-3)  # starts at the base speed at once
    assert prof.at(prof.end) == (6152, 0.0)


def test_the_limit_of_a_small_scan_by_hand() -> None:
    # 76 deg of pan at 20 % overlap: 2 views at pan -16.2 and 16.2 (fov 43.6, 32.4 deg apart,
    # within the 34.88 deg step); one tilt row at -30. From pan 0 tilt 0: 16.2 deg (315
    # positions) to the first view, then 32.4 deg (630 positions), at 1000 positions/s within
    # the base speed; the tilt's 30 deg (583 positions) go with the first pan move and are the
    # longer: 0.583 + 0.630 s of travel.
    motion = d46()
    pans, tilts = grid((-38, 38, -47.3, -12.7), FOV, 0.2)
    assert pans == [-16.2, 16.2] and tilts == [-30.0]
    limit = scan_limit((-38, 38, -47.3, -12.7), FOV, 0.2, None, motion, (0.0, 0.0), view_seconds=0.1)
    assert limit["views"] == 2
    assert limit["travel"] == pytest.approx(0.583 + 0.630, abs=2e-3)
    assert limit["total"] == pytest.approx(limit["travel"] + 0.2)


def is_serpentine(seq: list[tuple[float, float]], pans: list[float], tilts: list[float]) -> bool:
    """A boustrophedon over the grid: by rows or columns, each line swept one way, the next back."""
    for by_rows in (True, False):
        inner, outer = (pans, tilts) if by_rows else (tilts, pans)
        lines = [seq[i:i + len(inner)] for i in range(0, len(seq), len(inner))]
        keys = [[p if by_rows else t for p, t in line] for line in lines]
        if len(seq) == len(pans) * len(tilts) and all(
                k in (inner, inner[::-1]) for k in keys) and all(a != b for a, b in itertools.pairwise(keys)):
            consts = [{(t if by_rows else p) for p, t in line} for line in lines]
            if all(len(c) == 1 for c in consts) and sorted(c.pop() for c in consts) == sorted(outer):
                return True
    return False


@pytest.mark.parametrize("view_range", [(-180, 180, -50, -10), (-90, 90, -50, -15), (-60, 60, -80, 20),
                                        (0, 150, -40, -40)])
@pytest.mark.parametrize("start", [(0.0, 0.0), (150.0, -40.0), (-100.0, 20.0)])
@pytest.mark.parametrize("motion", [d46(), d46(base=0), d46(speed=2000, acceleration=4000)])
def test_the_planned_order_is_a_serpentine_no_slower_than_the_rows(view_range, start, motion) -> None:
    rows = get_ptu_positions(view_range, FOV, 0.3, LIMITS)  # the order without a motion model
    planned = get_ptu_positions(view_range, FOV, 0.3, LIMITS, motion=motion, start=list(start))
    pans, tilts = grid(view_range, FOV, 0.3, LIMITS)
    assert sorted(planned) == sorted(rows)  # the same views, the fewest
    assert is_serpentine(planned, pans, tilts) and is_serpentine(rows, pans, tilts)
    assert path_time(planned, motion, start) <= path_time(rows, motion, start) + 1e-9
    assert get_ptu_positions(view_range, FOV, 0.3, LIMITS, motion=motion, start=list(start), order="rows") == rows


def test_the_readme_scan_travels_in_columns_at_well_under_the_rows_time() -> None:
    motion = d46()
    rows = plan((-180, 180, -50, -10), FOV, 0.3, LIMITS, motion, (0.0, 0.0), "rows")
    planned = plan((-180, 180, -50, -10), FOV, 0.3, LIMITS, motion, (0.0, 0.0))
    assert len(planned) == 24
    assert planned[0][0] == planned[1][0] and planned[1][1] == planned[2][1]  # a column, then a pan step
    assert path_time(planned, motion, (0.0, 0.0)) < 0.7 * path_time(rows, motion, (0.0, 0.0))
    # starting where the last scan ended, the plan begins at that end of the range
    assert plan((-180, 180, -50, -10), FOV, 0.3, LIMITS, motion, planned[-1])[0] == planned[-1]


RANGE = "-45,45,-50,-15"  # 3 x 2 views


def scan_dem(server_factory, extra_sets: list[str], request_extra: str = "") -> tuple:
    srv = server_factory(["server.scene=quarry", *extra_sets])
    c = srv.client()
    r = c.request(f"dem-full-tof -range {RANGE} -name s {request_extra}", timeout=300)
    return srv, r


@long_test  # two scans of the same view range, ~5 s of CPU
def test_processing_while_the_ptu_moves_gives_the_same_dem(server_factory) -> None:
    srv_a, a = scan_dem(server_factory, ["dem_full_tof.overlap_processing=true"])
    srv_b, b = scan_dem(server_factory, ["dem_full_tof.overlap_processing=false"])
    assert a.status == b.status == "OK", (a.fields, b.fields)
    dem_a, g_a = read_geotiff(srv_a.data / a.fields["dem"])
    dem_b, g_b = read_geotiff(srv_b.data / b.fields["dem"])
    assert g_a == g_b
    np.testing.assert_array_equal(dem_a, dem_b)  # cell for cell, NaN where NaN
    assert int(a.fields["cells"]) == int(b.fields["cells"]) > 1000
    # the views and their order are recorded: the planned serpentine, from where the PTU stood
    scan = yaml.safe_load((srv_a.data / "dem/s_views/s_scan.yaml").read_text())
    positions = [tuple(p) for p in scan["positions"]]
    assert scan["order"] == "fastest" and scan["ptu_start"] == [0.0, 0.0]
    pans, tilts = sorted({p for p, _ in positions}), sorted({t for _, t in positions})
    assert len(positions) == 6 and is_serpentine(positions, pans, tilts)
    assert path_time(positions, scan["ptu_motion"], (0.0, 0.0)) == pytest.approx(min(
        path_time(plan([float(v) for v in RANGE.split(",")], FOV, 0.2, None, scan["ptu_motion"], (0.0, 0.0), o),
                  scan["ptu_motion"], (0.0, 0.0)) for o in ("fastest", "rows")), rel=0.05)
    with open(srv_a.data / "dem/s_views/s_images.csv") as fh:
        taken = [(round(float(r["pan"]), 1), round(float(r["tilt"]), 1)) for r in csv.DictReader(fh)]
    assert taken == [(round(p, 1), round(t, 1)) for p, t in positions]


def test_on_the_move_is_refused_where_it_would_blur_and_taken_where_it_would_not(server_factory) -> None:
    srv, r = scan_dem(server_factory, [], "-on-the-move")
    assert r.status == "ERROR" and r.fields["code"] == "E_ARG", r.fields
    msg = r.fields["message"]
    assert "blur the ToF views by" in msg and "px" in msg and "drivers.ptu.speed" in msg
    # at 50 positions/s (2.6 deg/s) the 45 ms of frames before the stop turn the head 0.5 px
    srv, r = scan_dem(server_factory, ["drivers.ptu.speed=50"], "-on-the-move")
    assert r.status == "OK", r.fields
    assert int(r.fields["views"]) == 6 and int(r.fields["cells"]) > 1000
    scan = yaml.safe_load((srv.data / "dem/s_views/s_scan.yaml").read_text())
    assert scan["on_the_move"] is True
