"""Read a scene file and turn its ``objects``, ``target`` and ``rover`` sections into objects.

Object ids: 0 terrain, 1 the rover, 2 the target, 3 the checkerboard, 10 and up the scene's
other objects in file order.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from drivers.sim.head import HeadGeometry
from drivers.sim.objects import (
    Box,
    Cylinder,
    Posed,
    SceneObject,
    Sphere,
    constant_albedo,
    marker_box_albedo,
)
from drivers.sim.rover import RoverBody
from drivers.sim.transforms import make_T, rot_x, rot_z

SCENES_DIR = Path(__file__).resolve().parents[2] / "config" / "scenes"

ROVER_ID = 1
TARGET_ID = 2
CHECKERBOARD_ID = 3
FIRST_OBJECT_ID = 10


def scene_path(name_or_path: str | Path) -> Path:
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") and p.exists():
        return p
    candidate = SCENES_DIR / f"{name_or_path}.yaml"
    if candidate.exists():
        return candidate
    known = sorted(q.stem for q in SCENES_DIR.glob("*.yaml"))
    raise FileNotFoundError(f"no scene {str(name_or_path)!r}; known scenes: {', '.join(known)}")


def load_scene_spec(name_or_path: str | Path, _seen: tuple[Path, ...] = ()) -> dict:
    """The scene's YAML as a dict, with ``_dir`` (its folder, where relative data files are
    looked up) added. ``extends: NAME`` takes that scene's sections and replaces the ones this
    file gives (whole sections, not merged key by key): another rock draw of a scene is its name
    and a ``seed``, with nothing copied that could drift from the original."""
    path = scene_path(name_or_path)
    if path.resolve() in _seen:
        raise ValueError(f"{path}: scenes extend each other in a loop ({' -> '.join(p.stem for p in _seen)})")
    with open(path) as f:
        spec = yaml.safe_load(f) or {}
    if not isinstance(spec, dict):
        raise ValueError(f"{path} is not a scene (a mapping with a terrain section)")
    base = spec.pop("extends", None)
    if base is not None:
        spec = {**load_scene_spec(str(base), (*_seen, path.resolve())), "name": path.stem, **spec,
                "extends": str(base)}
    if "terrain" not in spec:
        raise ValueError(f"{path} is not a scene (a mapping with a terrain section)")
    spec.setdefault("name", path.stem)
    spec.setdefault("_dir", str(path.resolve().parent))
    return spec


def build_object(spec: dict, oid: int) -> SceneObject:
    """A static object: ``wall`` (p0, p1, height, thickness), ``box`` (xyz of the base centre,
    size, yaw) or ``cylinder`` (xy, z, r, h). Heights are from ``z`` (default 0)."""
    kind = spec["type"]
    albedo = float(spec.get("albedo", 0.7))
    z = float(spec.get("z", 0.0))
    if kind == "wall":
        p0, p1 = np.asarray(spec["p0"], float), np.asarray(spec["p1"], float)
        length = float(np.linalg.norm(p1 - p0))
        yaw = float(np.degrees(np.arctan2(*(p1 - p0)[::-1])))
        th = float(spec.get("thickness", 0.1))
        shape = Box((-length / 2, -th / 2, 0.0), (length / 2, th / 2, float(spec.get("height", 2.5))))
        pose = make_T(rot_z(yaw), [*((p0 + p1) / 2), z])
    elif kind == "box":
        sx, sy, sz = (float(v) for v in spec["size"])
        shape = Box((-sx / 2, -sy / 2, 0.0), (sx / 2, sy / 2, sz))
        pose = make_T(rot_z(float(spec.get("yaw", 0.0))), spec["xyz"])
    elif kind == "cylinder":
        shape = Cylinder(float(spec["r"]), 0.0, float(spec["h"]))
        pose = make_T(None, [*spec["xy"], z])
    else:
        raise ValueError(f"unknown object type {kind!r}; known: wall, box, cylinder")
    return SceneObject(spec.get("name", f"{kind}{oid}"), oid, [shape], constant_albedo(albedo), pose,
                       in_dem=bool(spec.get("in_dem", True)), texture=float(spec.get("texture", 0.15)))


def build_target(spec: dict) -> SceneObject:
    """``astronaut``: a suited body (cylinder) with a head (sphere); ``marker_box``: a cube
    with an ArUco 6x6 marker on its four sides. Posed each time the target time changes."""
    kind = spec.get("type", "astronaut")
    if kind == "astronaut":
        h = float(spec.get("height", 1.8))
        r = float(spec.get("radius", 0.22))
        head = 0.13 * h / 1.8
        shapes = [Cylinder(r, 0.0, h - 2 * head), Sphere((0.0, 0.0, h - head), head)]
        alb = constant_albedo(float(spec.get("albedo", 0.85)))
        texture = 0.2
    elif kind == "marker_box":
        s = float(spec.get("size", 0.4))
        shapes = [Posed(Box((-s / 2, -s / 2, -s / 2), (s / 2, s / 2, s / 2)),
                        make_T(None, (0, 0, s / 2 + float(spec.get("lift", 0.0)))))]
        inner = marker_box_albedo(s / 2, int(spec.get("marker_id", 7)))
        lift = s / 2 + float(spec.get("lift", 0.0))

        def alb(p: np.ndarray, n: np.ndarray) -> np.ndarray:
            return inner(p - np.array([0.0, 0.0, lift]), n)

        texture = 0.0
    else:
        raise ValueError(f"unknown target type {kind!r}; known: astronaut, marker_box")
    return SceneObject("target", TARGET_ID, shapes, alb, in_dem=False, texture=texture,
                       visible=bool(spec.get("visible", True)))


def build_rover(spec: dict, head: HeadGeometry) -> SceneObject:
    """The rover's body as :class:`RoverBody` declares it (a box over four wheels at its hubs)
    and the mast up to just under the PTU, in the rover frame (origin on the ground under the
    rover centre)."""
    body = RoverBody.from_spec(spec.get("body"))
    L, W, H, wr, ww = body.length, body.width, body.height, body.wheel_radius, body.wheel_width
    shapes: list = [Box((-L / 2, -W / 2, body.clearance), (L / 2, W / 2, H))]
    for x, y in body.wheels:
        shapes.append(Posed(Cylinder(wr, -ww / 2, ww / 2), make_T(rot_x(90.0), (x, y, wr))))
    bx, by, bz = head.ptu_base
    m = float(spec.get("mast_width", 0.04))
    shapes.append(Box((bx - m / 2, by - m / 2, H), (bx + m / 2, by + m / 2, bz - 0.12)))
    return SceneObject("rover", ROVER_ID, shapes, constant_albedo(float(spec.get("albedo", 0.3))),
                       in_dem=False, texture=0.1)
