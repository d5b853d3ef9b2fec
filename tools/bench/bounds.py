"""Benchmark: the bounds map against the truth, beside the rolling map's 5 cm means (today's map).

A worst-case wheel and belly check is only as safe as its bounds hold and only as useful as they
are tight. Per scene and per way of looking, this prints:

- **held**: the share of cells with returns whose true highest ground (from the simulator's
  0.5 cm surface) lies under their upper bound; the target is >= 99.5 %;
- **upper - top** p50 / p99: how far above the true top the bound sits (tightness);
- **mean read low** p99: the rolling map's 5 cm cell mean under the true top of its cell, what
  the planner and the live check read today (the peer);
- **fuse ms** p50: one ToF frame into the bounds map, against the rolling map's fuse of the same
  frame (ratio);
- **bounded**: cells with an upper bound, and how many of them only by a ray passing over;
- **vehicle check**: the worst-case check of the four limits on the bounds at poses over the
  ground ahead, against the same check on the true 1 cm surface: poses it can judge (the others
  cover unseen ground), poses it calls safe that are not (must be 0), and the share of truly safe
  judged poses it still calls safe (what the rover may plan through).

Looks: ``one`` (one frame, pan 0, tilt -35), ``sweep`` (pans -40 / 0 / +40), ``approach`` (the
sweep, then a frame every 0.1 m over 2 m of straight drive, as the see loop sees the ground it
comes to), ``approach+hazcam`` (the same with the front hazard camera pair's frame at every step:
the simulated ``drivers.hazcam`` device as declared, its pair rendered and matched by the
server's stereo matcher, see :func:`hazcam`; fused as the see loop fuses them, as a stereo
frame), ``approach+stereo`` (the approach with the mast's own stereo pair every 0.4 m, at the
PTU's lowest tilt where it sees the ground 0.9-2.5 m ahead: the simulated PIKE pair at ``high``,
matched by the workflows' matcher with its declared noise over a search range that reaches the
nearest ground, every matched pixel fused as a stereo frame, see :func:`mast_stereo` and
``BoundsMap.fuse``'s ``sensor``). ToF range noise along each ray from the ToF's
noise model, height sigma from ``tof_height_variance``: the sigmas the map is given are the ones
the ToF frames were drawn with, so this measures the map, not a mis-stated sensor. The hazcam's
errors are real stereo errors against the sigmas its device declares, as are those of the
real-data row (Middlebury Motorcycle, against its ground-truth disparity).

``--poses`` states the vehicle check's safety as p-ACE (Ghosh, Otsu, Ono 2018) does, as a
measured probability: on world draws no setting was tuned on (:data:`POSE_DRAWS`), poses every
2 cm along straight paths over the judged ground (:func:`path_lines`), per scene and look the
judged poses, the false safe (the check on the bounds calls safe, the check on the true 1 cm
surface unsafe), the one-sided 95 % Clopper-Pearson bound on their rate per judged pose, the
truly safe kept, how many consecutive poses make one independent trial (the verdicts' integrated
autocorrelation along the paths) and the unsafe events per 100 m driven the bound allows.

    python -m tools.bench.bounds                       # marsyard, hirise, dense; all looks
    python -m tools.bench.bounds --poses --looks approach approach+hazcam approach+stereo --jobs 2
    python -m tools.bench.bounds --scenes hirise --looks approach --k 2.5 3
    python -m tools.bench.bounds --poses --looks standing --frames 1 8 --models main ray --jobs 2
    python -m tools.bench.bounds --calibrate-edge --draws 1 2 --frames 8

``standing`` is the see loop's standing look (:func:`standing`): the look planner's PTU positions,
the simulated SR4000's own frames averaging ``--frames``, fused with each of ``--models``
(:data:`MODELS`), judged over :data:`STANDING_BAND`. ``--calibrate-edge`` fits the grain and
rock-edge allowances on the truth (:func:`edge_calibration`).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

import cv2
import numpy as np

import drivers.hazcam as hazcam_device
import drivers.stereo as stereo_device
from drivers.ptu.protocol import D46_LIMITS, D46_RESOLUTION_ARCSEC, pos_to_deg
from drivers.sim.rover import RoverBody
from drivers.sim.world import World
from drivers.tof.constants import FOV_H_DEG, FOV_V_DEG, HEIGHT, USABLE_RANGE, WIDTH
from prox_workflows.algorithms.bounds_map import BoundsMap, BoundsParams
from prox_workflows.algorithms.dem2hazard import HazardParams
from prox_workflows.algorithms.noise import pair_sigmas, tof_height_variance, tof_horizontal_sigma, tof_sigma
from prox_workflows.algorithms.rolling_map import RollingMap, RollingParams
from prox_workflows.algorithms.stereo import disparity
from prox_workflows.algorithms.vehicle import LIMITS, check_poses, severity
from prox_workflows.grid import GridGeometry
from rvs_server.devices import stereo_points
from rvs_truth.stats import clopper_pearson_upper, events_per_distance_upper, poses_per_trial

LOOKS = ("one", "sweep", "approach", "approach+hazcam", "approach+stereo", "standing")
# the noise models the standing look's frames are fused with: ``main`` a return's sigma from its range
# alone, one frame's, spread over a disc; ``ray`` the amplitude and the frames averaged in the
# sigma, spread along the ray, with the rock-edge allowance (BoundsParams.edge)
MODELS = ("main", "ray")
# the ground a standing look's pose statistics judge, ahead of the rover's centre (m): the next drive
# and the one after it, past the mast's blind disc
STANDING_BAND = (1.0, 2.2)
MAST_STEREO = "high"  # the PIKE pair's mode for the near ground: 1280 x 960, 0.2 m baseline
MAST_STEREO_RANGE = 3.0  # m: the pair's points kept (the lowest tilt sees the ground to about 2.5 m)
# m: the matcher's nearest depth for the lowest tilt, whose nearest ground lies 1.15 m along the
# optical axis; at the matcher's default (1.5 m) the image's bottom rows are out of its search
# range, and what it matches there lands up to 1 m under the ground in islands past the speckle filter
MAST_STEREO_NEAR = 1.0
# one frame: points, height sigmas, sensor origin, horizontal sigmas, the range it was cut at, the
# kind of sensor (bounds_map.SENSORS)
Frame = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float, str]
TRUE_CELL = 0.005  # m: the truth's surface, pooled to the map's cells
PATH_STEP = 0.02  # m: poses along a path, as the live check judges one (vehicle.densify)
PATH_LATERAL = 0.08  # m: between the paths of the pose statistics (20,000 judged poses a scene in 3 draws)
# world draws for the pose statistics: no setting was tuned on them (the bench's own draws are
# seeds 1 and 2, the scenes' own seeds 3 / 15 / 20 are the navigate bench's and the limits')
POSE_DRAWS = (101, 102, 103)


def standing(world: World, n: int, model: str, seed: int) -> Iterator[tuple[Any, ...]]:
    """A standing look from the rover's pose at the PTU positions ``looks.standing_look`` plans
    (the lowest tilt and -35 deg over the pans the next drives' band needs), each frame the
    simulated SR4000's (drivers.tof on the world: its amplitude, mixed pixels at depth edges,
    multipath, on-chip filter) averaging ``n`` frames, its pixels kept as the see loop keeps them
    (``hazard_monitor.ground_pixels``, not the rover's own body), fused with ``model``'s sigmas."""
    import drivers.tof as tof_device
    from prox_workflows.algorithms.hazard_monitor import ground_pixels
    from prox_workflows.algorithms.looks import View, on_body, standing_look
    from prox_workflows.algorithms.noise import tof_spread
    from prox_workflows.algorithms.transforms import HeadCalibration
    from rvs_server.navigation.see import EDGE_JUMP

    device = tof_device.create({"backend": "sim", "seed": seed, "time_scale": 0}, world)
    device.open()
    body = RoverBody()
    lowest = pos_to_deg(D46_LIMITS["tilt"][0], D46_RESOLUTION_ARCSEC)
    view = View(FOV_H_DEG, FOV_V_DEG, lowest)
    pose = world.rover_pose()
    T_rw = np.linalg.inv(world.T_world_rover())
    try:
        for pan, tilt in standing_look(pose, HeadCalibration(), view, body.length, body.width):
            world.set_ptu(pan, tilt)
            T = np.asarray(world.sensor_pose("tof"), dtype=np.float64)
            xyz, amplitude = device.grab_xyz(n, 0.0)
            keep = ground_pixels(xyz, 1, USABLE_RANGE, amplitude, 0.1, EDGE_JUMP)
            cam = xyz[keep].astype(np.float64)
            pts = cam @ T[:3, :3].T + T[:3, 3]
            own = on_body(pts @ T_rw[:3, :3].T + T_rw[:3, 3], body)
            pts, cam, amp = pts[~own], cam[~own], amplitude[keep][~own]
            origin = T[:3, 3]
            if model == "main":
                yield (pts, np.sqrt(tof_height_variance(pts, origin)).astype(np.float64), origin,
                       tof_horizontal_sigma(pts, origin).astype(np.float64), USABLE_RANGE, "tof")
                continue
            raw, mhz = device.noise_amplitude(amp, np.linalg.norm(cam, axis=1))
            sigma, along, across = tof_spread(pts, origin, raw, frames=n, frequency_mhz=mhz)
            yield pts, sigma, origin, along, USABLE_RANGE, "tof", across
    finally:
        device.close()


def tof_frame(world: World, rng: np.random.Generator, pan: float, across: bool = True) -> dict[str, Any]:
    """One simulated ToF frame of ``world`` at ``pan`` (tilt -35 deg), the returns with the range
    noise the camera is told of, as :meth:`BoundsMap.fuse`'s arguments (``points``, ``sigma``,
    ``origin``, then ``args`` and ``kwargs``): the looks here and the tests fuse the same frame.
    ``across``: each return's horizontal error an ellipse along its ray (a quarter of it across),
    as the see loop fuses its frames, else a disc."""
    world.set_ptu(pan, -35.0)
    origin = world.sensor_pose("tof")[:3, 3]
    view = world.render_sensor("tof", WIDTH, HEIGHT)
    ranges = view.range.reshape(-1)
    keep = np.isfinite(ranges) & (ranges < USABLE_RANGE) & (view.object_id.reshape(-1) != 1)
    pts, r = view.points.reshape(-1, 3)[keep].astype(np.float64), ranges[keep].astype(np.float64)
    noisy = pts + (pts - origin) / r[:, None] * (tof_sigma(r) * rng.standard_normal(len(r)))[:, None]
    along = tof_horizontal_sigma(noisy, origin)
    return {"points": noisy, "sigma": np.sqrt(tof_height_variance(noisy, origin)), "origin": origin,
            "args": (USABLE_RANGE, along), "kwargs": {"sigma_across": along / 4 if across else None}}


def frames(world: World, look: str, rng: np.random.Generator) -> Iterator[Frame]:
    """Each frame of a way of looking."""
    x0, y0, h0 = world.rover_pose()
    front = pair = None
    if look == "approach+hazcam":
        front = hazcam_device.create({"cameras": "front"}, world, stereo_points)
        front.open()
    if look == "approach+stereo":
        pair = stereo_device.create({"backend": "sim"}, world)
        pair.open()

    def grab(pan: float) -> Frame:
        f = tof_frame(world, rng, pan)
        return (f["points"], f["sigma"].astype(np.float64), f["origin"], f["args"][1].astype(np.float64),
                USABLE_RANGE, "tof")

    pans = (0.0,) if look == "one" else (-40.0, 0.0, 40.0)
    for pan in pans:
        yield grab(pan)
    if look.startswith("approach"):
        for i in range(1, 21):
            world.set_rover_pose(x0 + 0.1 * i, y0, h0)
            yield grab(0.0)
            if front is not None:
                yield hazcam(world, front)
            if pair is not None and i % 4 == 1:
                yield mast_stereo(world, pair)
        world.set_rover_pose(x0, y0, h0)


def hazcam(world: World, device: hazcam_device.Hazcam) -> Frame:
    """The front hazcam pair's frame in the world frame, with its declared range sigma split
    into height and horizontal parts (and half a pixel across the ray)."""
    frame = device.grab("front")
    T = world.T_world_rover()
    pts = frame.points @ T[:3, :3].T + T[:3, 3]
    origin = T[:3, :3] @ frame.origin + T[:3, 3]
    sigma, sigma_xy = pair_sigmas(pts, origin, frame.sigma_range, device.rig("front").focal)
    return pts, sigma, origin, sigma_xy, device.config.max_range, "stereo"  # as the see loop fuses it


def mast_stereo(world: World, pair: stereo_device.StereoPair) -> Frame:
    """The mast's stereo pair at the PTU's lowest tilt: every matched pixel in the world frame,
    its range sigma from the matcher's declared disparity noise, split as the hazcam's is."""
    world.set_ptu(0.0, pos_to_deg(D46_LIMITS["tilt"][0], D46_RESOLUTION_ARCSEC))
    left, right = pair.grab_stereo_direct(MAST_STEREO)
    d = disparity(left, right, pair.calibration(MAST_STEREO), {"min_depth": MAST_STEREO_NEAR})
    pts = d.points().reshape(-1, 3).astype(np.float64)
    sigma_z = d.sigma_z().reshape(-1).astype(np.float64)
    keep = np.isfinite(pts).all(axis=1) & np.isfinite(sigma_z) & (pts[:, 2] < MAST_STEREO_RANGE)
    pts, sigma_z = pts[keep], sigma_z[keep]
    T = np.asarray(world.sensor_pose("left"), dtype=np.float64)
    origin = T[:3, 3]
    sigma_range = sigma_z * np.linalg.norm(pts, axis=1) / pts[:, 2]  # along the ray, not the optical axis
    world_pts = pts @ T[:3, :3].T + origin
    sigma, sigma_xy = pair_sigmas(world_pts, origin, sigma_range, d.rect.focal)
    return world_pts, sigma, origin, sigma_xy, MAST_STEREO_RANGE, "stereo"


def pooled(fine: np.ndarray, g: GridGeometry, how: Any) -> np.ndarray:
    f = int(round(g.cell / TRUE_CELL))
    return how(fine[:g.height * f, :g.width * f].reshape(g.height, f, g.width, f), axis=(1, 3))


def looked(world: World, look: str, k: float, seed: int, n: int = 1, model: str = "ray",
           edge: float | None = None) -> tuple[BoundsMap, RollingMap, list[float], list[float]]:
    """The bounds map and the rolling map after a way of looking from the world's rover start
    (ToF noise drawn from ``seed``), with each frame's fuse time in each. The standing look
    averages ``n`` frames a position and is fused with ``model`` (:data:`MODELS`; ``main`` draws
    no grain or rock-edge allowance, ``edge`` overrides the declared one)."""
    x0, y0, _ = world.rover_pose()
    box = [[x0 - 1.0, y0 - 3.0], [x0 + 6.5, y0 + 3.0]]
    params = BoundsParams(k=k)
    if model == "main":
        params.edge = params.grain = 0.0
    elif edge is not None:
        params.edge = edge
    bounds = BoundsMap.covering(box, 0.0, params)
    rolling = RollingMap(RollingParams(size=12.0), HazardParams(), (x0 + 2.5, y0))
    t_bounds, t_rolling = [], []
    source = standing(world, n, model, seed) if look == "standing" else frames(world, look, np.random.default_rng(seed))
    for pts, sigma, origin, sigma_xy, cut, sensor, *across in source:
        t0 = time.perf_counter()
        bounds.fuse(pts, sigma, origin, cut, sigma_xy, sensor, across[0] if across else None)
        t1 = time.perf_counter()
        rolling.fuse(pts, np.linalg.norm(pts - origin, axis=1))
        t2 = time.perf_counter()
        t_bounds.append(t1 - t0)
        t_rolling.append(t2 - t1)
    return bounds, rolling, t_bounds, t_rolling


def sim_row(scene: str, look: str, k: float, seed: int = 0, body: RoverBody | None = None) -> dict[str, Any]:
    world = World.from_scene(scene, seed=1)
    x0, y0, _ = world.rover_pose()
    bounds, rolling, t_bounds, t_rolling = looked(world, look, k, seed)
    g = bounds.geometry
    fine = world.true_dem(TRUE_CELL, (g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax))
    top = pooled(fine, g, np.max)
    seen = np.isfinite(bounds.mean)
    upper = bounds.upper
    # the peer: the rolling map's 5 cm means under the true top of their own cells
    rg = rolling.geometry
    rfine = world.true_dem(TRUE_CELL, (rg.xmin, rg.ymin, rg.xmin + rg.width * rg.cell, rg.ymax))
    rtop = pooled(rfine, rg, np.max)
    rseen = np.isfinite(rolling.height)
    ceiling_only = np.isfinite(bounds.ceiling) & ~seen
    first = 1 if len(t_bounds) > 1 else 0  # the first call compiles the ray kernel
    # the vehicle check on the bounds against the same check on the true 1 cm surface, at poses
    # over the ground ahead (4 headings each)
    truth = world.true_dem(0.01, (g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax))
    tg = GridGeometry(0.01, g.xmin, g.ymax, truth.shape[1], truth.shape[0])
    px, py = np.meshgrid(x0 + np.arange(1.6, 4.0, 0.1), y0 + np.arange(-1.2, 1.25, 0.1))
    poses = np.column_stack([np.repeat(px.ravel(), 4), np.repeat(py.ravel(), 4),
                             np.tile([0.0, 45.0, 90.0, 135.0], px.size)])
    body = body or RoverBody()
    on_truth = check_poses(truth, tg, poses, body)
    on_bounds = check_poses((bounds.lower, upper), g, poses, body)
    judged = ~on_bounds.unknown
    truly_safe = judged & ~on_truth.unsafe
    return {
        "scene": scene, "look": look, "k": k, "frames": len(t_bounds),
        "held": float(np.mean(top[seen] <= upper[seen])),
        "held_ceiling": float(np.mean(top[ceiling_only] <= upper[ceiling_only])) if ceiling_only.any() else float("nan"),
        "over_p50": float(np.percentile(upper[seen] - top[seen], 50)),
        "over_p99": float(np.percentile(upper[seen] - top[seen], 99)),
        "mean_low_p99": float(np.percentile(rtop[rseen] - rolling.height[rseen], 99)),
        "fuse_ms": 1000 * float(np.median(t_bounds[first:])),
        "rolling_ms": 1000 * float(np.median(t_rolling[first:])),
        "bounded": int(seen.sum() + ceiling_only.sum()), "ceiling_only": int(ceiling_only.sum()),
        "poses": len(poses), "judged": int(judged.sum()), "false_safe": int((on_truth.unsafe & on_bounds.safe).sum()),
        "safe_kept": float(on_bounds.safe[truly_safe].mean()) if truly_safe.any() else float("nan"),
        "truly_safe": int(truly_safe.sum()),
        # why the truly safe poses the bounds refuse are refused: step, belly, stability, grade (a pose may have several)
        "refused_by": [int(n) for n in (on_bounds.excess[truly_safe & on_bounds.unsafe] > 0).sum(axis=0)],
    }


def path_lines(x0: float, y0: float, spacing: float = PATH_STEP, lateral: float = PATH_LATERAL,
               headings: tuple[float, ...] = (0.0, 45.0, 90.0, 135.0), band: tuple[float, float] = (1.6, 4.0)
               ) -> list[np.ndarray]:
    """Straight paths across the judged ground ahead (x0 + ``band`` (1.6..4.0), y0 - 1.2..1.2, as
    the pose grid of :func:`sim_row`), at each of ``headings``, ``lateral`` apart, a pose every
    ``spacing`` along each, as the live check judges a path (``vehicle.densify``'s 2 cm)."""
    lo, hi = np.array([x0 + band[0], y0 - 1.2]), np.array([x0 + band[1], y0 + 1.2])
    centre, half = (lo + hi) / 2, float(np.hypot(*(hi - lo))) / 2
    out = []
    for h in headings:
        u = np.array([np.cos(np.radians(h)), np.sin(np.radians(h))])
        nrm = np.array([-u[1], u[0]])
        along = np.arange(-half, half + 1e-9, spacing)
        for off in np.arange(-half, half + 1e-9, lateral):
            xy = centre + off * nrm + along[:, None] * u
            xy = xy[((xy >= lo) & (xy <= hi)).all(axis=1)]
            if len(xy) >= 2:
                out.append(np.column_stack([xy, np.full(len(xy), h)]))
    return out


def pose_row(scene: str, look: str, k: float, world_seed: int, body: RoverBody | None = None, n: int = 1,
             model: str = "ray", edge: float | None = None) -> dict[str, Any]:
    """The live check's verdicts on one world draw, per pose along :func:`path_lines`: the check
    on the bounds map after ``look`` (ToF noise drawn from ``world_seed`` too; the standing look
    with ``n`` frames a position and noise ``model``, judged over :data:`STANDING_BAND`) against
    the check on the true 1 cm surface. Per path, each judged pose's verdicts (1 unsafe, 0 safe,
    NaN unjudged) for the correlation length."""
    t0 = time.perf_counter()
    world = World.from_scene(scene, seed=world_seed)
    x0, y0, _ = world.rover_pose()
    bounds, _, _, _ = looked(world, look, k, world_seed, n, model, edge)
    g = bounds.geometry
    truth = world.true_dem(0.01, (g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax))
    tg = GridGeometry(0.01, g.xmin, g.ymax, truth.shape[1], truth.shape[0])
    paths = path_lines(x0, y0, band=STANDING_BAND if look == "standing" else (1.6, 4.0))
    poses = np.concatenate(paths)
    body = body or RoverBody()
    on_truth = check_poses(truth, tg, poses, body)
    on_bounds = check_poses((bounds.lower, bounds.upper), g, poses, body)
    judged = ~on_bounds.unknown
    truly_safe = judged & ~on_truth.unsafe
    false_safe = on_truth.unsafe & on_bounds.safe
    cuts = np.cumsum([len(p) for p in paths])[:-1]
    # what the truth holds against each false-safe pose: each limit it passes, by how much (m for
    # step and belly, deg for the angles) and how badly
    misses = [", ".join(f"{name} {e:+.3g} ({severity(name, e)})" for name, e in zip(LIMITS, on_truth.excess[i], strict=True)
                        if e > 0) + f" at ({poses[i, 0]:.2f}, {poses[i, 1]:.2f}, {poses[i, 2]:.0f})"
              for i in np.flatnonzero(false_safe)]
    # one false-safe event per run of consecutive false-safe poses along a path
    events = sum(int(np.count_nonzero(np.diff(np.concatenate([[0], f.astype(np.int8), [0]])) == 1))
                 for f in np.split(false_safe, cuts))
    if look == "standing":
        look = f"standing {n} frame{'s' if n > 1 else ''}, {model}"
    return {
        "scene": scene, "look": look, "world_seed": world_seed, "poses": len(poses), "judged": int(judged.sum()),
        "truly_safe": int(truly_safe.sum()), "false_safe": int(false_safe.sum()), "events": events,
        "safe_kept": int(on_bounds.safe[truly_safe].sum()),
        "misses": misses,
        "truth_paths": np.split(np.where(judged, on_truth.unsafe, np.nan), cuts),
        "live_paths": np.split(np.where(judged, ~on_bounds.safe, np.nan), cuts),
        "seconds": time.perf_counter() - t0,
    }


def pose_table(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per scene and look, over its world draws: judged poses, false safe, the one-sided 95 %
    Clopper-Pearson bound on the false-safe rate per judged pose, the truly safe kept, the poses a
    trial (the longer correlation of the truth's and the live check's verdicts along the paths;
    one body length where the verdicts never vary) and the unsafe events per 100 m it allows."""
    out = []
    for key in dict.fromkeys((r["scene"], r["look"]) for r in rows):
        rs = [r for r in rows if (r["scene"], r["look"]) == key]
        n, fs = sum(r["judged"] for r in rs), sum(r["false_safe"] for r in rs)
        taus = [poses_per_trial([p for r in rs for p in r[which]]) for which in ("truth_paths", "live_paths")]
        taus = [t for t in taus if t == t]
        per_trial = max(taus) if taus else RoverBody().length / PATH_STEP
        out.append({"scene": key[0], "look": key[1], "draws": [r["world_seed"] for r in rs],
                    "poses": sum(r["poses"] for r in rs), "judged": n, "false_safe": fs,
                    "events": sum(r["events"] for r in rs), "rate_upper": clopper_pearson_upper(fs, n) if n else float("nan"),
                    "kept": sum(r["safe_kept"] for r in rs) / max(1, sum(r["truly_safe"] for r in rs)),
                    "per_trial": per_trial, "per_100m": events_per_distance_upper(sum(r["events"] for r in rs), n,
                                                                                  per_trial, PATH_STEP) if n else float("nan"),
                    "seconds": sum(r["seconds"] for r in rs)})
    return out


def print_pose_table(table: list[dict[str, Any]]) -> None:
    print("| scene | look | world draws | judged / poses | false safe (events) | rate per judged pose, 95 % upper "
          "| truly safe kept | poses a trial (cm) | unsafe events per 100 m, 95 % upper | s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for t in table:
        print(f"| {t['scene']} | {t['look']} | {' '.join(map(str, t['draws']))} | {t['judged']} / {t['poses']} "
              f"| {t['false_safe']} ({t['events']}) | {t['rate_upper']:.2e} | {100 * t['kept']:.1f} % "
              f"| {t['per_trial']:.1f} ({100 * PATH_STEP * t['per_trial']:.0f}) | {t['per_100m']:.2f} | {t['seconds']:.0f} |")


def motorcycle_cloud() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Middlebury Motorcycle (quarter size, scikit-image) matched by the project's stereo: its points
    as a height map over the floor plane (camera x right, z ahead; height = -y), their height and
    horizontal sigmas from the matcher's own noise model, and the ground-truth disparity's points.
    None (and why, printed) where scikit-image or its data is absent."""
    try:
        from skimage.data import stereo_motorcycle

        left, right, truth = stereo_motorcycle()
    except Exception as exc:  # the test extra (scikit-image) absent or its data missing
        print(f"Motorcycle skipped: {exc}")
        return None
    from prox_workflows.algorithms import stereo as st

    f, b, doffs = 994.978, 0.193001, 31.086  # the pair's calibration (scikit-image's docstring)
    gl, gr = (cv2.cvtColor(a, cv2.COLOR_RGB2GRAY) for a in (left, right))
    params = st.SgbmParams()
    disp = st.disparity_rectified(gl, gr, params, 80)
    h, w = gl.shape
    v, u = np.mgrid[0:h, 0:w]

    def cloud(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ok = np.isfinite(d) & (d > 0)
        z = f * b / (d[ok] + doffs)
        x = (u[ok] - w / 2) * z / f
        y = (v[ok] - h / 2) * z / f
        return np.column_stack([x, z, -y]), z  # map x, map y (ahead), height

    pts, z = cloud(disp)
    true_pts, _ = cloud(truth.astype(np.float32))
    sigma_z = st.depth_sigma(z, b, f, st.sigma_d_for(params.scale))
    r = np.linalg.norm(pts, axis=1)
    up_share = np.abs(pts[:, 2]) / np.maximum(r, 1e-9)  # the depth error's share along the height
    sigma = np.sqrt((sigma_z * up_share) ** 2 + (0.0015 * r) ** 2)
    sigma_xy = np.sqrt(sigma_z**2 * (1.0 - up_share**2) + (0.0015 * r) ** 2)
    return pts, sigma, sigma_xy, true_pts


def motorcycle_row(k: float) -> dict[str, Any] | None:
    """The Motorcycle pair's points (:func:`motorcycle_cloud`) fused as one stereo frame, its bounds
    drawn with the matcher's own noise model, against the ground-truth disparity's points."""
    got = motorcycle_cloud()
    if got is None:
        return None
    pts, sigma, sigma_xy, true_pts = got
    bounds = BoundsMap.covering(true_pts[:, :2], 0.05, BoundsParams(k=k))
    t0 = time.perf_counter()
    bounds.fuse(pts, sigma, np.zeros(3), None, sigma_xy, "stereo")
    fuse_ms = 1000 * (time.perf_counter() - t0)
    g = bounds.geometry
    rr, cc = g.cell_of(true_pts[:, 0], true_pts[:, 1])
    top = np.full(g.shape, np.nan, np.float32)
    inside = g.inside(rr, cc)
    np.fmax.at(top, (rr[inside], cc[inside]), true_pts[inside, 2].astype(np.float32))
    seen = np.isfinite(bounds.mean) & np.isfinite(top)
    upper = bounds.upper
    return {"scene": "Motorcycle (real)", "look": "one pair", "k": k, "frames": 1,
            "held": float(np.mean(top[seen] <= upper[seen])), "held_ceiling": float("nan"),
            "over_p50": float(np.percentile(upper[seen] - top[seen], 50)),
            "over_p99": float(np.percentile(upper[seen] - top[seen], 99)),
            "mean_low_p99": float("nan"), "fuse_ms": fuse_ms, "rolling_ms": float("nan"),
            "bounded": int(seen.sum()), "ceiling_only": 0, "poses": 0, "judged": 0, "false_safe": 0,
            "safe_kept": float("nan"), "truly_safe": 0, "refused_by": None}


def edge_calibration(scenes: list[str], draws: list[int], n: int, k: float) -> None:
    """The rock-edge and grain allowances (``BoundsParams.edge``, ``grain``) fitted on the truth:
    after the standing look with ``n`` frames and the ``ray`` model without them, on world draws
    no pose statistics are taken on, per cell with returns the true top (the 0.5 cm surface's
    highest in the cell) over its upper bound, against the relief its 3 x 3 neighbourhood spans
    (``BoundsMap.edge_allowance`` at edge 1, grain 0). Prints the share of cells held per grain
    and edge, and per band of relief at the declared pair."""
    misses, spans = [], []
    for scene in scenes:
        for draw in draws:
            world = World.from_scene(scene, seed=draw)
            bounds, _, _, _ = looked(world, "standing", k, draw, n, "ray", 0.0)
            bounds.params.grain = 0.0
            g = bounds.geometry
            fine = world.true_dem(TRUE_CELL, (g.xmin, g.ymin, g.xmin + g.width * g.cell, g.ymax))
            top = pooled(fine, g, np.max)
            seen = np.isfinite(bounds.mean)
            whole = (slice(0, g.height), slice(0, g.width))
            misses.append((top - bounds.upper)[seen])
            bounds.params.edge = 1.0
            spans.append(bounds.edge_allowance(whole)[seen])
            print(f"{scene} draw {draw}: {int(seen.sum())} cells, held {100 * np.mean(misses[-1] <= 0):.2f} %",
                  file=sys.stderr, flush=True)
    miss, span = np.concatenate(misses), np.concatenate(spans)
    grains, edges = [0.0, 0.002, 0.003, 0.005, 0.008], [0.0, 0.05, 0.1, 0.2, 0.3]
    print(f"world draws {draws}, {n} frames a position, k {k}, {len(miss)} cells: the share whose true top the "
          "upper bound holds")
    print("| grain (mm) | " + " | ".join(f"edge {e:g}" for e in edges) + " |")
    print("|---|" + "---|" * len(edges))
    for a in grains:
        print(f"| {1000 * a:g} | " + " | ".join(f"{100 * np.mean(miss <= a + e * span):.2f} %" for e in edges) + " |")
    p = BoundsParams()
    bands = [0.0, 0.02, 0.05, 0.1, 0.2, np.inf]
    print(f"at the declared grain {1000 * p.grain:g} mm and edge {p.edge:g}, per band of relief (cm): " + ", ".join(
        f"{100 * lo:g}-{100 * hi:g} {100 * np.mean((miss <= p.grain + p.edge * span)[(span >= lo) & (span < hi)]):.2f} %"
        f" of {int(((span >= lo) & (span < hi)).sum())}" for lo, hi in zip(bands[:-1], bands[1:], strict=True)
        if ((span >= lo) & (span < hi)).any()))


def print_rows(rows: list[dict[str, Any]]) -> None:
    print("| scene | look | k | frames | held | held (ray only) | upper - top p50 / p99 (cm) | 5 cm mean read low p99 (cm) "
          "| fuse ms (rolling map; ratio) | bounded (ray only) | vehicle check: judged / false safe / truly safe kept "
          "(of) | truly safe refused by step / belly / stability / grade |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        ratio = r["fuse_ms"] / r["rolling_ms"] if r["rolling_ms"] == r["rolling_ms"] else float("nan")
        print(f"| {r['scene']} | {r['look']} | {r['k']:g} | {r['frames']} | {100 * r['held']:.2f} % "
              f"| {100 * r['held_ceiling']:.2f} % | {100 * r['over_p50']:.1f} / {100 * r['over_p99']:.1f} "
              f"| {100 * r['mean_low_p99']:.1f} | {r['fuse_ms']:.1f} ({r['rolling_ms']:.1f}; {ratio:.2f}) "
              f"| {r['bounded']} ({r['ceiling_only']}) | {r['judged']}/{r['poses']} / {r['false_safe']} "
              f"/ {100 * r['safe_kept']:.1f} % ({r['truly_safe']}) | {' / '.join(map(str, r['refused_by'] or ['-']))} |")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", nargs="+", default=["marsyard", "hirise", "dense"])
    ap.add_argument("--looks", nargs="+", choices=LOOKS, default=list(LOOKS))
    ap.add_argument("--k", nargs="+", type=float, default=[BoundsParams().k])
    ap.add_argument("--no-real", action="store_true", help="leave out the Motorcycle row")
    ap.add_argument("--body", action="append", default=[], metavar="KEY=VALUE",
                    help="a RoverBody field for the vehicle check (e.g. clearance=0.16): what a body with other "
                         "margins would keep")
    ap.add_argument("--poses", action="store_true",
                    help="the pose-level statistics instead: the live check's false-safe rate per judged pose along "
                         "paths over world draws no setting was tuned on, with its 95 %% bound")
    ap.add_argument("--draws", nargs="+", type=int, default=list(POSE_DRAWS), help="world seeds for --poses")
    ap.add_argument("--jobs", type=int, default=1, help="processes for --poses (one row each)")
    ap.add_argument("--frames", nargs="+", type=int, default=[1, 8],
                    help="frames the standing look's camera averages a position (each a row)")
    ap.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS),
                    help="noise models the standing look's frames are fused with (each a row)")
    ap.add_argument("--edge", type=float, default=None, help="the rock-edge allowance (BoundsParams.edge) for --poses")
    ap.add_argument("--calibrate-edge", action="store_true",
                    help="fit the rock-edge allowance (BoundsParams.edge) on the truth instead, on --draws "
                         "(use draws the pose statistics do not: 1 2)")
    args = ap.parse_args(argv)
    if args.calibrate_edge:
        edge_calibration(args.scenes, args.draws, max(args.frames), args.k[0])
        return
    body = dataclasses.replace(RoverBody(), **{key: float(v) for key, v in (a.split("=", 1) for a in args.body)})
    if args.poses:
        todo = [(s, look, k, d, body, n, m, args.edge) for k in args.k for s in args.scenes for look in args.looks
                for n, m in ([(n, m) for m in args.models for n in args.frames] if look == "standing" else [(1, "ray")])
                for d in args.draws]
        with ProcessPoolExecutor(args.jobs) as pool:
            futures = [pool.submit(pose_row, *t) for t in todo]
            for f in as_completed(futures):
                r = f.result()
                print(f"{r['scene']} {r['look']} draw {r['world_seed']}: {r['judged']} judged, "
                      f"{r['false_safe']} false safe, {r['seconds']:.0f} s", *r["misses"], sep="; ", file=sys.stderr,
                      flush=True)
            prows = [f.result() for f in futures]
        print(f"world draws {args.draws}, k {args.k}, a pose every {100 * PATH_STEP:.0f} cm along paths "
              f"{100 * PATH_LATERAL:.0f} cm apart at 4 headings")
        print_pose_table(pose_table(prows))
        return
    rows = [sim_row(s, look, k, body=body) for k in args.k for s in args.scenes for look in args.looks]
    if not args.no_real:
        rows += [r for k in args.k if (r := motorcycle_row(k)) is not None]
    print_rows(rows)


if __name__ == "__main__":
    main()
