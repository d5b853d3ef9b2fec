"""The path planner's parameters: :class:`PlanParams`, the settings the operator and the
scripts set (the ``plan_path`` step's own settings), and
:class:`PlannerParams`, what :func:`.planner.plan_path` is called with, which takes its
defaults and checks from them and adds what the caller knows of the rover."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields
from typing import Any

from rvs_params import Settings, param


@dataclass
class PlanParams(Settings):
    """Path planning on hazard and slope maps (a navigate leg, ``rvs-path-planner``): the settings an
    operator or a script sets. :class:`PlannerParams`, what :func:`plan_path` is called with,
    takes its defaults and checks from here and adds what the caller knows of the rover."""

    weight: float = param(0.5, "A* weight w: 1 distance only, 0 environmental cost only", min=0.0, max=1.0)
    heuristic: str = param("octile", "A* heuristic", choices=("euclidean", "manhattan", "octile"))
    grid: float = param(0.05, "planning cell size", unit="m", min=0.01, max=1.0)
    margin: float = param(0.1, "added to the rover radius around hazards", unit="m", min=0.0, max=2.0)
    max_deviation: float = param(0.1, "waypoint polyline's largest deviation from the A* path", unit="m",
                                 min=0.0, max=5.0)
    border: float = param(1.0, "stop this far inside the locally seen ground: at least the radius the next "
                          "scan cannot see around the rover, so the legs join; halved (down to 0) where the "
                          "seen ground is too narrow for the rover to move at all", unit="m", min=0.0, max=5.0)
    footprint: str = param("circle", "what must clear the hazards: circle, the rover's circumscribed circle (radius + "
                           "margin) along the whole path; body, its half width + margin along straight stretches "
                           "and the circle only where it stops and turns on the spot (waypoints and the goal), "
                           "which opens the gaps of a rock field that the circle closes", choices=("circle", "body"))


_PLAN = PlanParams()


@dataclass(frozen=True)
class PlannerParams:
    """The planner's parameters (metres and degrees)."""

    grid: float | None = None  # planning cell size; default: the local map's
    weight: float = _PLAN.weight  # w: 1 distance only, 0 environmental cost only
    heuristic: str = _PLAN.heuristic
    rover_radius: float = 0.3
    half_width: float | None = None  # footprint "body": straight stretches keep this + margin from hazards
    margin: float = _PLAN.margin
    critical_slope: float = 20.0  # degrees: c = 1 here
    unknown_cost: float = 1.0  # c of unknown ground (inf: not traversable)
    max_deviation: float = _PLAN.max_deviation  # of the waypoint polyline from the A* path
    border: float = 0.3  # stop this far inside the local map's outer border
    blank_pad: float = 2.0  # blank global maps reach this far beyond start, goal and local map
    window: float | None = None  # plan only within this margin around start, goal and local map

    def __post_init__(self) -> None:
        specs = PlanParams.specs()  # the operator's range and choices are the planner's own
        specs["weight"].coerce(self.weight, "planner")
        specs["heuristic"].coerce(self.heuristic, "planner")
        for name in ("rover_radius", "margin", "max_deviation", "border", "blank_pad"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0")
        if self.grid is not None and not self.grid > 0:
            raise ValueError("grid must be > 0")
        if not self.critical_slope > 0:
            raise ValueError("critical_slope must be > 0")
        if not self.unknown_cost >= 0:
            raise ValueError("unknown_cost must be >= 0 (inf forbids unknown ground)")

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def of(cls, plan: PlanParams | Mapping[str, Any], *, rover_radius: float, half_width: float | None = None,
           critical_slope: float, unknown_cost: float | None = None) -> PlannerParams:
        """The planner's parameters from the operator's ``plan`` settings (or a script's
        parameters) and what the caller knows of its rover: every setting both classes declare is
        taken by name, so a setting declared in both here reaches every caller (a navigate leg, the
        see loop, the plan_leg script, rvs-path-planner) with no other change. ``half_width`` is
        used for the ``body`` footprint only."""
        given = plan.as_dict() if isinstance(plan, PlanParams) else dict(plan)
        shared = {f.name: given[f.name] for f in fields(cls) if f.name in given and f.name in PlanParams.specs()}
        footprint = given.get("footprint", _PLAN.footprint)
        if footprint == "body" and half_width is None:
            raise ValueError("footprint body needs the rover's half width")
        return cls(**shared, rover_radius=rover_radius, half_width=half_width if footprint == "body" else None,
                   critical_slope=critical_slope, **({} if unknown_cost is None else {"unknown_cost": unknown_cost}))
