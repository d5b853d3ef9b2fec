"""navigate's configuration: the mission's own keys and its ``plan``, ``see`` and
``localisation`` sections, each declared once. The sections lend their keys to navigate
(``flat``): the request's options (``-weight``, ``-localise``), ``--set navigate.see_margin``
and ``config -set navigate.border`` name them as before, and ``navigate.see.margin`` names the
same key in its section. Each section goes whole to the part of navigation that reads it (the
planner, the see strategy, the localiser).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from prox_workflows.algorithms.bounds_map import BoundsParams
from prox_workflows.algorithms.candidates import CandidateParams
from prox_workflows.algorithms.chance import ChanceParams
from prox_workflows.algorithms.planner import PlanParams
from prox_workflows.algorithms.retreat import RetreatParams
from rvs_params import Settings

from ..config import ModuleConfig, param


@dataclass
class SeeConfig(Settings):
    """The see loop (``-loop see``): drive while checking the next metres with the forward ToF."""

    period: float = param(1.0, "see loop: simulated time driven between two forward ToF frames (1 s: 10 cm at "
                          "0.1 m/s; each simulated frame is rendered, which costs CPU)", unit="s", min=0.05, max=10.0,
                          option=False)
    lookahead: float = param(1.5, "see loop: the footprint is checked this far along the path ahead", unit="m",
                             min=0.2, max=5.0, option=False)
    tilt: float = param(-35.0, "see loop: PTU tilt of the forward ToF", unit="deg", min=-90.0, max=0.0, option=False)
    subsample: int = param(2, "see loop: use every n-th ToF pixel in both directions", min=1, max=8, option=False)
    margin: float = param(0.05, "see loop: added around the rover body in the check", unit="m", min=0.0, max=1.0,
                          option=False)
    max_range: float = param(3.0, "see loop: ignore ToF points farther than this (a single frame's returns beyond "
                             "3 m are sparse and noisy enough to make phantom steps near the goal)", unit="m",
                             min=0.5, max=30.0, option=False)
    replan_ahead: float = param(1.0, "see loop: extend the path from the rolling map once the leg's end is this "
                                "close, without stopping", unit="m", min=0.0, max=5.0, option=False)
    pursuit: float = param(0.3, "see loop: the rover steers at the point of its path this far ahead (pure pursuit; "
                           "shorter follows the waypoints' corners closer)", unit="m", min=0.05, max=3.0,
                           option=False)
    arc_turn: float = param(45.0, "see loop: a heading error up to this is driven out as an arc at full speed, a "
                            "larger one is turned on the spot", unit="deg", min=0.0, max=180.0, option=False)
    unseen: str = param("off", "see loop: ground no map has seen under the rover's sweep over the next see_blind "
                        "metres (the forward ToF sees from about a metre ahead of the rover, so it will not see "
                        "that ground before the body is on it): look stops and looks at it, then drives on; keep "
                        "also ends the leg when the look does not show it and keeps plans off such ground that "
                        "close (plus half the body) as off a rock (experimental: it can stall where a scan leaves "
                        "the way on unseen); off drives on (docs/PROTOCOL.md)", choices=("look", "keep", "off"),
                        option=False)
    blind: float = param(0.8, "see loop: the stretch of path ahead that see_unseen judges", unit="m", min=0.0,
                         max=3.0, option=False)
    memory: float = param(0.0, "see loop: keep what the rolling map saw for the whole mission, over the box of "
                          "start and goal grown by this (8 is a fair box), so a dead end driven out of is not "
                          "planned into again once it scrolls off the 8 m rolling map; experimental, its false "
                          "hazards are kept too (docs/PROTOCOL.md); 0: not kept", unit="m", min=0.0, max=100.0,
                          option=False)
    border: float = param(0.3, "see loop: plans stop this far inside the seen ground (the forward ToF sees the "
                          "ground ahead before the rover gets there; a scan leg keeps navigate.border)", unit="m",
                          min=0.0, max=5.0, option=False)
    search: str = param("dstar", "see loop: the search of a replan: dstar repairs the mission's last search with "
                        "the cells that changed (D* Lite, the same path cost as astar), astar searches again",
                        choices=("dstar", "astar"), option=False)
    localise_every: float = param(2.0, "see loop with -localise map or both: match the rolling map on the global "
                                  "DEM after every this many metres driven, and after every leg closer than this "
                                  "to the goal", unit="m", min=0.1, max=1000.0, option=False)
    arrival_spread: float = param(120.0, "see loop with -localise map or both: on arriving, the rover looks round "
                                  "standing (three ToF frames, this far either side of ahead: the ground behind "
                                  "too, which a goal near the map's edge needs) and matches what they saw on the "
                                  "global DEM", unit="deg", min=0.0, max=150.0, option=False)
    gate: str = param("bounds", "see loop: bounds plans every section with the vehicle check on a map of each "
                      "cell's height bounds and statistics (ENav's choice: candidate arcs ranked by cost and the "
                      "cost to go, checked in that order, the first section that passes driven; ground no frame "
                      "bounded is looked at, never driven on); off plans on the 5 cm maps and trusts their hazard "
                      "check alone", choices=("bounds", "off"), option=False)
    vehicle: str = param("chance", "see loop with see_gate bounds: the vehicle check the sections are chosen and "
                       "driven by: chance, the probability that the body exceeds a limit given each cell's "
                       "posterior, at most epsilon (see_chance.epsilon); bounds, the worst case on the bounds",
                       choices=("chance", "bounds"), option=False)
    set_down: str = param("ring", "see loop with the bounds map: the ground where the rover is set down that no "
                          "frame shows (the mast's blind disc, under the body): level takes it within 1 cm of level; "
                          "attitude takes it within 1 cm of the plane the rover's IMU gives (drivers.rover attitude: "
                          "the simulator's, the GNC's pose -roll -pitch) and the ground under the wheels no higher "
                          "than that plane, down to 2.5 cm below it (a rigid body rests on three wheels), where the "
                          "rover stands throughout the drive; without an attitude, level; ring (with the chooser), after "
                          "the first look round, takes the wheels' ground from the pose and the IMU's attitude, and "
                          "the rest of the blind disc and of the disc the body turns in (the "
                          "ground between the wheels included) on the plane fitted to the seen ground just outside it, "
                          "carried continuously into the ground known beside it, within that ground's own spread "
                          "about the plane, less near known ground (at least 1 cm), never over the belly's ceiling "
                          "(prox_workflows.algorithms.set_down); with attitude and ring, while driving, the body "
                          "rests on the ground frames bounded under its wheels, tipped by the attitude, over every "
                          "pose it passed between two frames (BoundsMap.stood)", choices=("level", "attitude", "ring"),
                          option=False)
    keep_moved: float = param(2.0, "see loop with the bounds map: a navigate that starts this near where the last "
                              "one left the rover (a drive of the GNC's own between goals) takes that one's map and "
                              "is set down again where it stands, the set-down filling only what the map's frames "
                              "did not bound: backed out of where it was first set down, the rover turns on ground "
                              "those frames saw (docs/NAVIGATE_BENCH.md). Where it still stands it needs no set-down; "
                              "farther than this, after sim move-rover or with other map settings, a fresh map "
                              "(0: only where the rover still stands)", unit="m", min=0.0, max=10.0, option=False)
    register: bool = param(True, "see loop with the gate: a rover that has not moved keeps its last frame's "
                           "height, and each frame taken after a move is placed on the ground the bounds map holds "
                           "(the median of its cells' heights less the map's, over well-known flat ground) instead "
                           "of at the map's height round the rover's centre (false: that datum, which moved 2.7 cm "
                           "(p95) from frame to frame against the truth where registered frames move 0.4 mm, and "
                           "the map read the frames' disagreement as relief; docs/NAVIGATE_BENCH.md). Needs "
                           "navigate.see.bounds.changed: the frames' agreement no longer widens a dropped rock's "
                           "unseen flank", option=False)
    gaze: str = param("path", "see loop with the gate: where the ToF looks while driving: path pans along the path "
                      "(the ground a turn will put under the wheels), frames in turn at the path just ahead at the "
                      "lowest tilt (where the gate judges next) and further on at see_tilt; off, or see_gate off, holds pan 0 and "
                      "see_tilt (a PTU move is sent with the cycle's motion and slews while the wheels turn; the next frame waits for the mast to stand)",
                      choices=("path", "off"), option=False)
    start_look: bool = param(True, "see loop with see_gaze path: a section's first frame is taken standing, the "
                             "mast aimed along the section, and the section's rest judged on it before the first "
                             "motion; false sets off at once (the first frame after the first motion, its look sent "
                             "with it): marsyard 0-9 took 6-26 % less time in 9 missions (12 % more in one), but 4 of "
                             "19 dropped rocks were touched (within the limits), and dense 0-4 reached 0 of 5 (1 with "
                             "the look; docs/NAVIGATE_BENCH.md)",
                             option=False)
    gaze_hold: int = param(1, "see loop with see_gaze path: frames the gaze holds its near look, then its far one; "
                           "above 1, within a hold the mast pans again only for a turn (the path's bearing 15 deg "
                           "off its pan). 1 reached 10 of marsyard's 10 missions, 3 reached 9 "
                           "(docs/NAVIGATE_BENCH.md)", min=1, max=20, option=False)
    look_frames: int = param(8, "see loop with the gate: frames the ToF averages (grab-tof -integrate) at each "
                             "position of a look taken standing: its range noise falls as 1 / sqrt(frames), each "
                             "frame costs its exposure on the clock (a frame taken while driving is one)",
                             min=1, max=100, option=False)
    drive_frames: int = param(1, "see loop with the gate: frames the ToF averages for each frame taken while "
                              "driving: exposed while the wheels turn, they cost no standing time (about 20 ms a "
                              "frame: 2 mm of travel)", min=1, max=16, option=False)
    look_drive: float = param(1.0, "see loop with the gate: a look taken standing shows the ground the body covers "
                              "driving this far in a fan of +-60 deg ahead, and as far again beyond, from the mast's "
                              "blind disc out (prox_workflows.algorithms.looks: the lowest tilt and see_tilt)",
                              unit="m", min=0.1, max=3.0, option=False)
    start_turn: float = param(60.0, "see loop with the gate and the body's hazard cameras on (drivers.hazcam.cameras): "
                              "at the start, after the first look round, the rover turns on the spot in steps of "
                              "this, each judged safe first, a frame of every pair at each heading, until the pairs "
                              "have looked all round (both pairs: 3 headings; one pair: 6): they show the ground "
                              "between the body and the mast's blind disc, which the set-down then need not assume; "
                              "0: no turn", unit="deg", min=0.0, max=180.0, option=False)
    max_replans: int = param(100, "see loop: give up after this many plans in all", min=1, max=10000, option=False)
    # declared where they are used (prox_workflows.algorithms), set here: navigate.see.chooser.section=0.8
    chooser: CandidateParams = param(CandidateParams(), "see loop with the gate: the candidate paths and the "
                                     "costs that rank them (prox_workflows.algorithms.candidates)")
    chance: ChanceParams = param(ChanceParams(), "see loop with the gate, see_vehicle chance: the risk a section "
                                 "may carry (epsilon) and how its probability is drawn")
    ahead: str = param("best", "see loop with the gate: the check of each candidate's look-ahead beyond its "
                       "section, which refuses (or prices: navigate.see.chooser.ahead_cost) the section where it "
                       "fails: best, the posterior's best estimate (the section is judged in full before it is "
                       "driven); chance, the section's own check, at about 1.4-2.3x a choice's CPU",
                       choices=("chance", "best"), option=False)
    bounds: BoundsParams = param(BoundsParams(), "see loop with the gate: the bounds map's cell and how wide its "
                                 "bounds are drawn round each frame (prox_workflows.algorithms.bounds_map)")
    retreat: RetreatParams = param(RetreatParams(), "see loop with the gate: backing out of dead ends (no candidate "
                                   "passes, or no progress) and the cost a dead end leaves on the cost to go "
                                   "(prox_workflows.algorithms.retreat)")


@dataclass
class LocaliseConfig(Settings):
    """Knowing where the rover is between legs (:mod:`rvs_server.navigation.localiser`)."""

    localise: str = param("none", "correct the dead-reckoned pose after each leg: vo (the leg's DEM on the last "
                          "one), map (on the global DEM), both, or none", choices=("none", "vo", "map", "both"))
    drift: float = param(0.05, "dead reckoning's position error per metre driven (1 sigma, share of distance)",
                         min=0.0, max=1.0, option=False)
    heading_drift: float = param(2.0, "dead reckoning's heading error per metre driven (1 sigma)", unit="deg/m",
                                 min=0.0, max=90.0, option=False)


@dataclass
class NavigateConfig(ModuleConfig):
    module: ClassVar[str] = "navigate"
    goal: list[float] = param([], "goal x,y in the global frame", unit="m", length=2, min=-1e6, max=1e6,
                              required=True)
    start: list[float] = param([], "start x,y[,heading] (default: the current pose)", unit="m,m,deg",
                               length=(2, 3), min=-1e6, max=1e6)
    sensor: str = param("tof", "sensor for the 360-degree DEMs", choices=("tof", "stereo", "fused"))
    auto: bool = param(False, "simulated rover only: drive the waypoints without waiting for pose (as "
                       "drivers.rover.backend=sim does for every navigate)")
    tolerance: float = param(0.3, "the goal is reached within this distance", unit="m", min=0.05, max=10.0)
    max_legs: int = param(12, "give up after this many legs", min=1, max=200)
    name: str = param("", "stem of the products (default nav_<UTC time>)", stem=True)
    # the planner's parameters are declared once, in prox_workflows.parameters.PlanParams (the
    # plan_leg script and rvs-path-planner read the same declarations)
    plan: PlanParams = param(PlanParams(), "the planner's parameters", flat="")
    range: list[float] = param([-180.0, 180.0, -50.0, -10.0], "view range of each leg's DEM", unit="deg",
                               length=4, min=-360.0, max=360.0, option=False, ordered=True)
    overlap: float = param(0.3, "view overlap of each leg's DEM", min=0.0, max=0.9, option=False)
    wait_timeout: float = param(60.0, "a leg's wait for the GNC ends E_DATA when no pose report leaves the leg's "
                                "start within this time (a GNC gone, or one that never drives; 0: wait forever)",
                                unit="s", min=0.0, max=86400.0, option=False)
    pose_settle: float = param(2.0, "a leg's wait for the GNC ends when its pose, once it left the leg's start, "
                               "holds still this long (reported again or not), or at pose -stopped true; a pose "
                               "near the leg's end while moving does not end it; also how long a navigate whose "
                               "connection closed waits for a pose from another", unit="s", min=0.05, max=600.0, option=False)
    pose_still: list[float] = param([0.01, 1.0], "pose reports within this distance and heading of the first of "
                                    "them hold still", unit="m,deg", length=2, min=0.0, max=10.0, option=False)
    judge_range: float = param(3.0, "a goal judged unreachable (goal_in_hazard, enclosed) from farther than this "
                               "is driven toward and judged again from closer, where the ToF sees it densely and "
                               "reliably (its returns thin out and get noisier toward the 4.5 m it keeps)", unit="m",
                               min=0.0, max=50.0, option=False)
    min_progress: float = param(0.1, "a leg that starts closer than this to the previous leg's start made no "
                                "progress; the second such leg in a row ends the job", unit="m", min=0.0, max=5.0,
                                option=False)
    global_maps: str = param("", "folder with global hazard.tif and slope.tif, and dem.tif for map matching "
                             "(empty: blank maps, or -global)", option=False)
    global_: str = param("", "global DEM (or 0/128/255 hazard map) GeoTIFF from orbit, in any CRS in metres; "
                         "its hazard and slope come from Dem2Hazard, its heights serve map matching (instead of "
                         "navigate.global_maps)")
    global_origin: list[float] = param([0.0, 0.0], "the rover frame's origin (the start) in the global map's CRS",
                                       unit="m", length=2, min=-1e8, max=1e8)
    localisation: LocaliseConfig = param(LocaliseConfig(), "knowing where the rover is", flat="")
    # see is the default: judged by the vehicle (an unsafe event under the body's physical limits
    # fails a mission) the scan loop failed 4 of 10 marsyard missions on the belly and 14 of 20 in
    # hirise and dense, the see loop 8 of 90, ending the missions it does not reach in a safe stop
    # (docs/NAVIGATE_BENCH.md, "At the counts")
    loop: str = param("see", "see looks standing with the forward ToF, chooses each section (at most 1 m) ENav's "
                      "way, checked by the rover's own body on a map of height bounds, and checks it again while "
                      "it drives (-auto: every cycle; the GNC: at every pose report); no 360-degree scan unless "
                      "-localise matches scans; scan stops for a 360-degree scan where it starts and again scan_stretch "
                      "metres on (or, with -scan-plan circle, at every leg's end, the leg planned on its hazard "
                      "map)", choices=("see", "scan"))
    scan_plan: str = param("chooser", "scan loop: how the rover goes on from each 360-degree scan: chooser, by the see "
                           "loop's sections (each chosen by the vehicle check on the bounds map after a look round "
                           "standing, and checked again on the frames taken while it drives) until it stands "
                           "scan_stretch from the last scan; circle, the plan_leg script's path on the scan's hazard "
                           "map (the rover as a circle on Dem2Hazard's thresholds), driven to its end",
                           choices=("chooser", "circle"))
    scan_stretch: float = param(3.0, "scan loop with scan_plan chooser: the next 360-degree scan is made once the "
                                "rover stands this far from the last one (about the ground a scan shows densely)",
                                unit="m", min=0.2, max=50.0, option=False)
    see: SeeConfig = param(SeeConfig(), "the see loop", flat="see_")
