"""tools.bench.gate_trace's judgements of a stop and of an unsafe event, as plain functions on a
synthetic ground: a 12 cm ledge under the rover's turn, known to the map to 5 mm."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from drivers.sim.rover import RoverBody
from prox_workflows.algorithms.bounds_map import BoundsParams
from prox_workflows.algorithms.chance import ChanceParams
from prox_workflows.algorithms.vehicle import PoseChecks, check_poses
from prox_workflows.grid import GridGeometry
from tools.bench.gate_trace import axis_trace, chance_spacings, detail, readings, trace_events, turn_trace

BODY = RoverBody()


def on(h: np.ndarray, g: GridGeometry) -> Callable[[np.ndarray], PoseChecks]:  # the truth judging poses on ``h``
    def truth(poses: np.ndarray) -> PoseChecks:
        return check_poses(h, g, poses, BODY)
    return truth


def ground() -> tuple[np.ndarray, GridGeometry]:
    g = GridGeometry.covering(-1.0, -1.0, 1.0, 1.0, 0.025)
    xs, ys = g.centers()
    X, _ = np.meshgrid(xs, ys)
    return np.where(X > 0.2, 0.12, 0.0).astype(np.float32), g


def one_choice(h: np.ndarray, g: GridGeometry, sigma: float, refused: list[list[float]]) -> dict[str, np.ndarray]:
    """A dump (:func:`tools.bench.gate_trace.dump`) of one choice whose map knows ``h`` to ``sigma``."""
    z = np.zeros(h.shape, np.float32)
    return {"c0_mean": h, "c0_mean_var": np.full(h.shape, sigma**2, np.float32), "c0_rise": z, "c0_drop": z,
            "c0_relief": z, "c0_shift": z, "c0_along_var": z, "c0_ceiling": np.full(h.shape, np.inf, np.float32),
            "c0_framed": np.ones(h.shape, bool), "c0_lower": h, "c0_upper": h,
            "c0_geom": np.array([g.cell, g.xmin, g.ymax, g.width, g.height], float), "c0_k": np.array(2.5),
            "c0_pose": np.zeros(3), "c0_refused": np.array(refused, float)}


def test_a_refusal_is_judged_per_limit_on_the_map_the_draws_and_the_truth() -> None:
    h, g = ground()
    z = np.zeros(h.shape, np.float32)
    stats = {"mean": h, "mean_var": np.full(h.shape, 0.005**2, np.float32), "rise": z, "drop": z, "shift": z,
             "along_var": z, "ceiling": np.full(h.shape, np.inf, np.float32), "lower": h, "upper": h}
    choices = [{"pose": [0.0, 0.0, 0.0], "map": (stats, g, BoundsParams().k), "chance": ChanceParams()}]
    refusals = [{"pose": [0.0, 0.0, 0.0], "choice": 0, "where": "choose"},  # the ledge under the front wheels
                {"pose": [-0.5, 0.0, 0.0], "choice": 0, "where": "choose"}]  # flat ground behind it
    out = detail(choices, refusals, on(h, g), BODY, draws=16)
    assert len(out) == 2
    ledge, flat = out
    assert ledge["truth_unsafe"] and not flat["truth_unsafe"]
    assert ledge["best"][0] > 0.0 and ledge["truth"][0] > 0.0 and ledge["prob"][0] > 0.5  # the step, all three
    assert flat["best"][0] < -0.05 and flat["draw_max"][0] < 0.0 and flat["prob"][0] < 1e-3
    assert ledge["from_rover"] == 0.0 and flat["from_rover"] == 0.5
    assert np.isnan(ledge["framed"])  # a map with no frame stamps: the share unknown
    xs, _ = g.centers()
    framed = np.broadcast_to(xs < -0.5, h.shape)  # frames bounded only the ground west of x -0.5
    out = detail([{**choices[0], "map": ({**stats, "framed": framed}, g, BoundsParams().k)}], refusals, on(h, g),
                 BODY, draws=16)
    assert out[0]["framed"] == 0.0 and 0.3 < out[1]["framed"] < 0.7  # the flat pose's middle straddles x -0.5


def test_an_event_is_traced_to_the_nearest_chosen_pose_and_the_truth_there() -> None:
    h, g = ground()
    section = [[-0.5, 0.0, 0.0], [-0.3, 0.0, 0.0], [0.0, 0.0, 0.0]]
    choices = [{"pose": [-0.5, 0.0, 0.0], "section": section, "section_p_any": 1e-6}]
    events = [{"kind": "step front-left", "excess": 0.02, "x": 0.01, "y": 0.005, "heading": 2.0},
              {"kind": "belly", "excess": 0.001, "x": -0.29, "y": 0.01, "heading": 0.0}]
    chosen_unsafe, strayed = trace_events(events, choices, on(h, g), BODY)
    assert chosen_unsafe["nearest"] == [0.0, 0.0, 0.0] and chosen_unsafe["planned_truly_unsafe"]
    assert abs(chosen_unsafe["off_m"] - np.hypot(0.01, 0.005)) < 1e-9 and chosen_unsafe["off_deg"] == 2.0
    assert strayed["nearest"] == [-0.3, 0.0, 0.0] and not strayed["planned_truly_unsafe"]
    assert strayed["section_p_any"] == 1e-6 and strayed["choice"] == 0
    assert "at_event" not in strayed  # the choice kept no map


def test_an_event_is_judged_at_its_true_pose_on_the_map_the_choice_read() -> None:
    """The ledge's step at the event's pose: a map that reads the ledge 12 cm low passes that pose
    (the check's false safe, though the nearest chosen pose is truly safe); a map that knows the
    ledge refuses it (the track strayed from what was judged)."""
    h, g = ground()
    section = [[-0.5, 0.0, 0.0], [-0.3, 0.0, 0.0]]
    event = {"kind": "step front-left", "excess": 0.02, "x": 0.0, "y": 0.0, "heading": 0.0}
    judged = {}
    for name, read in (("low", np.zeros_like(h)), ("right", h)):
        stats = {k[3:]: v for k, v in one_choice(read, g, 0.002, [[0.0, 0.0, 0.0]]).items()}
        choices = [{"pose": [-0.5, 0.0, 0.0], "section": section, "section_p_any": 1e-6,
                    "map": (stats, g, BoundsParams().k), "chance": ChanceParams()}]
        (traced,) = trace_events([event], choices, on(h, g), BODY)
        assert not traced["planned_truly_unsafe"]  # the nearest chosen pose, 0.3 m back, is truly safe
        judged[name] = traced["at_event"]
    assert judged["low"]["passed"] and judged["low"]["p_any"] <= ChanceParams().epsilon
    assert judged["low"]["best"][0] < 0.0  # the map's step at the event: none
    assert not judged["right"]["passed"] and judged["right"]["best"][0] > 0.0


def test_the_stop_s_turn_names_the_frames_spread_that_refuses_it_on_flat_ground() -> None:
    """Flat true ground; the map's means are right to 1 mm and each frame's returns show no relief,
    but between the left wheels, on the circle they turn on, the frames disagree by 12 cm (the top
    12 cm over the mean): the turn is refused each way where a wheel meets it, and passes all round
    with the spread taken out; no other term's removal passes it."""
    g = GridGeometry.covering(-1.0, -1.0, 1.0, 1.0, 0.025)
    flat = np.zeros((g.height, g.width), np.float32)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    # on the wheels' circle midway between the left wheels (0.145, +-0.245 and -0.145, 0.245): the
    # front-left wheel comes there turning 30 deg left, the rear-left turning 30 deg right
    wx, wy = 0.0, float(np.hypot(0.145, 0.245))
    spread = (np.abs(X - wx) < 0.025) & (np.abs(Y - wy) < 0.025)  # 2 x 2 cells
    z = np.zeros_like(flat)
    rise = np.where(spread, 0.12, 0.0).astype(np.float32)
    stats = {"mean": flat, "mean_var": np.full(flat.shape, 0.001**2, np.float32), "rise": rise, "drop": z,
             "relief": z, "shift": z, "along_var": z, "ceiling": np.full(flat.shape, np.inf, np.float32),
             "framed": np.ones(flat.shape, bool), "lower": flat, "upper": flat + rise}
    turn = turn_trace(stats, g, BoundsParams().k, (0.0, 0.0, 0.0), on(flat, g), BODY, ChanceParams(), step=5.0)
    left, right = turn["left"], turn["right"]
    assert left["truth"] == 360.0 and right["truth"] == 360.0
    for way in (left, right):
        assert 0.0 <= way["check"] < 30.0  # the pose itself passes; refused as a wheel reaches the spread
        assert way["without"]["frames' spread"] == 360.0
        assert all(deg < 360.0 for name, deg in way["without"].items() if name != "frames' spread")


def test_a_steep_flank_reads_as_a_step_where_the_map_s_samples_span_more_than_the_truth_s() -> None:
    """A rise of 3.5 m a metre (74 deg) is 7 cm within the truth's 2 cm of a wheel's lane, under
    the 10 cm climb. On 2.5 cm cells the bounds check reads each sample from its cell, 1.75 cm
    apart, so two samples span two cells' rise, 17.5 cm; the chance check reads its surfaces
    bilinearly a cell apart, so two samples span 5 cm, 17.5 cm too: a step the ground does not have.
    Read bilinearly at the truth's 1 cm it is the truth's 7 cm again."""
    fine = GridGeometry.covering(-1.0, -1.0, 1.0, 1.0, 0.01)
    g = GridGeometry.covering(-1.0, -1.0, 1.0, 1.0, 0.025)

    def ramp(geom: GridGeometry) -> np.ndarray:
        xs, ys = geom.centers()
        X, _ = np.meshgrid(xs, ys)
        return np.clip((X - 0.10) * 3.5, 0.0, 0.5).astype(np.float32)

    dumped = one_choice(ramp(g), g, 0.002, [[0.0, 0.0, 0.0], [-0.6, 0.0, 0.0]])
    table = readings(dumped, on(ramp(fine), fine), BODY)
    assert table["truth"]["step"]["over"] == 0
    for reading in ("best estimate, the bounds check's", "best estimate, the chance check's"):
        step = table[reading]["step"]
        assert step["false_over"] == 1 and step["median_error"] > 0.03, (reading, step)  # the ramp; not the flat
    for reading in ("best estimate, the truth's 1 cm", "cell means, the truth's 1 cm"):
        step = table[reading]["step"]
        assert step["over"] == 0 and abs(step["median_error"]) < 0.01, (reading, step)


def test_the_chance_check_is_judged_again_at_each_spacing_against_the_truth() -> None:
    """The 12 cm ledge under the front wheels is refused at every spacing of the draws' samples and
    truly unsafe; flat ground behind it passes at every spacing: no false safe, no false refusal."""
    h, g = ground()
    table = chance_spacings(one_choice(h, g, 0.005, [[0.0, 0.0, 0.0], [-0.5, 0.0, 0.0]]), on(h, g), BODY)
    assert set(table) == {"a cell (the check's)", "0.7 of a cell", "the truth's 1 cm"}
    for row in table.values():
        assert row == {"judged": 2, "passed": 1, "false_safe": 0, "false_refusal": 0}, row


def test_the_way_out_along_the_body_s_axis_is_named_where_the_turn_sweeps_unseen_ground() -> None:
    """Flat true ground. The map knows it to 2 mm everywhere but in a band round the rover where it
    was set down (within 0.45 m, off the body's own lane): there only a prior 4 cm wide, as the
    set-down's. Along the body's axis the lane is seen, so the straight passes either way, and
    0.6 m along it the turn's disc is wholly framed and the turn passes all round; 0.3 m along,
    the disc still reaches the band."""
    g = GridGeometry.covering(-2.0, -1.0, 2.0, 1.0, 0.025)
    flat = np.zeros((g.height, g.width), np.float32)
    xs, ys = g.centers()
    X, Y = np.meshgrid(xs, ys)
    band = (np.hypot(X, Y) <= 0.45) & (np.abs(Y) > 0.31)
    z = np.zeros_like(flat)
    stats = {"mean": flat, "mean_var": np.where(band, 0.04**2, 0.002**2).astype(np.float32), "rise": z, "drop": z,
             "relief": z, "shift": z, "along_var": z, "ceiling": np.full(flat.shape, np.inf, np.float32),
             "framed": ~band, "lower": flat, "upper": flat}
    way = axis_trace(stats, g, BoundsParams().k, (0.0, 0.0, 0.0), on(flat, g), BODY, ChanceParams())
    for side in ("ahead", "back"):
        a = way[side]
        assert a["passes"] == 1.2 and a["truth"] == 1.2 and a["first_refusal"] is None
        near, *beyond = a["turns"]
        assert near["at"] == 0.3 and near["framed"] < 1.0 and near["check"] < near["truth"] == near["headings"]
        for t in beyond:
            assert t["framed"] == 1.0 and t["check"] == t["truth"] == t["headings"]
    # the strip behind the body's end that no pair shows: the straight back is refused where the
    # rear wheels reach it, and the trace names that pose against the truth's margin there
    strip = band | ((X > -0.36) & (X < -0.26))
    stats.update(mean_var=np.where(strip, 0.04**2, 0.002**2).astype(np.float32), framed=~strip)
    back = axis_trace(stats, g, BoundsParams().k, (0.0, 0.0, 0.0), on(flat, g), BODY, ChanceParams())["back"]
    first = back["first_refusal"]
    assert back["passes"] < 0.3 and back["truth"] == 1.2
    assert first["at"] == round(back["passes"] + 0.02, 3) and first["p"] > ChanceParams().epsilon
    assert max(first["truth"][:2]) < -0.05  # the truth: each wheel 10 cm under its climb, the belly 8 cm clear
