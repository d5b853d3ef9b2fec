"""Simulation control (only when backends are simulated): move or drive the rover, make its
wheels slip, read the truth, change the scene or add a rock to it, inject device faults. For
tests, demos and benchmarks; a real rover has none of it."""

from __future__ import annotations

import asyncio
from dataclasses import dataclass
from typing import Any, ClassVar

from drivers.registry import Capability, fault_kinds

from ..app import Context
from ..config import ModuleConfig, param, standalone
from ..protocol import Fixed, ProtocolError
from ..table import ALWAYS, apply_options, command

FAULT_KINDS = fault_kinds()  # declared once, by each device's simulator backend


@standalone
@dataclass
class SimConfig(ModuleConfig):
    """The simulated world (``--set sim.key=value``, ``config -module sim``): its one clock."""

    module: ClassVar[str] = "sim"
    time_scale: float = param(1.0, "simulated seconds per wall second of the simulated world's clock, on which "
                              "the rover drives (sim drive, navigate -auto), the PTU moves and the ToF takes "
                              "frames: 1 real time, 10 ten times faster, 0 instant (time still counts)",
                              min=0.0, max=100000.0)


@dataclass
class SimMoveRoverConfig(ModuleConfig):
    module: ClassVar[str] = "sim_move_rover"
    dx: float = param(0.0, "forward motion in the rover frame", unit="m", min=-100.0, max=100.0)
    dy: float = param(0.0, "leftward motion in the rover frame", unit="m", min=-100.0, max=100.0)
    dyaw: float = param(0.0, "turn, counter-clockwise", unit="deg", min=-360.0, max=360.0)


@dataclass
class SimFaultConfig(ModuleConfig):
    module: ClassVar[str] = "sim_fault"
    device: str = param("ptu", "device", choices=tuple(FAULT_KINDS), required=True)
    kind: str = param("none", "fault to inject, or none to clear it",
                      choices=("none",) + tuple(sorted({k for v in FAULT_KINDS.values() for k in v})))


@dataclass
class SimDriveConfig(ModuleConfig):
    module: ClassVar[str] = "sim_drive"
    v: float | None = param(None, "forward speed (default: the scene's rover speed, 0.1 m/s unless its rover: "
                            "block says otherwise)", unit="m/s", min=-5.0, max=5.0)
    w: float = param(0.0, "turn rate, counter-clockwise", unit="deg/s", min=-180.0, max=180.0)
    seconds: float = param(1.0, "how long to drive, in simulated time", unit="s", min=0.0, max=3600.0)


@dataclass
class SimSlipConfig(ModuleConfig):
    module: ClassVar[str] = "sim_slip"
    distance: float = param(0.0, "share of the commanded distance the rover falls short by (0.05: 5 %)",
                            min=0.0, max=0.9)
    heading: float = param(0.0, "heading drift per metre driven, to one side (drawn from -seed)", unit="deg/m",
                           min=0.0, max=90.0)
    seed: int = param(0, "seed of the slip draws", min=0, max=2**31 - 1)


@dataclass
class SimAddRockConfig(ModuleConfig):
    module: ClassVar[str] = "sim_add_rock"
    x: float = param(0.0, "rock centre x in the global frame", unit="m", min=-1e4, max=1e4, required=True)
    y: float = param(0.0, "rock centre y in the global frame", unit="m", min=-1e4, max=1e4, required=True)
    radius: float = param(0.15, "rock radius", unit="m", min=0.01, max=5.0)
    height: float = param(0.2, "rock height above the ground", unit="m", min=0.01, max=5.0)


@dataclass
class NoOptions(ModuleConfig):
    module: ClassVar[str] = "sim_none"


VERBS: dict[str, type[ModuleConfig]] = {
    "move-rover": SimMoveRoverConfig,
    "drive": SimDriveConfig,
    "slip": SimSlipConfig,
    "truth": NoOptions,
    "scene": NoOptions,
    "add-rock": SimAddRockConfig,
    "fault": SimFaultConfig,
}


def _truth(world: Any) -> dict[str, Any]:
    """The true pose and PTU, with the rover's dead-reckoned pose and the simulated time beside
    them: with slip the two poses part, and that gap is what a localiser must close."""
    t = world.truth()
    return {"x": Fixed(t["x"], 4), "y": Fixed(t["y"], 4), "z": Fixed(t["z"], 4), "heading": Fixed(t["heading"], 3),
            "roll": Fixed(t["roll"], 3), "pitch": Fixed(t["pitch"], 3), "pan": Fixed(t["pan"], 3),
            "tilt": Fixed(t["tilt"], 3), "odom_x": Fixed(t["odom_x"], 4), "odom_y": Fixed(t["odom_y"], 4),
            "odom_heading": Fixed(t["odom_heading"], 3),
            "sim_time": Fixed(t["sim_time"], 3)}


@command("sim", klass=ALWAYS, raw=True, sim_only=True,
         positional=("move-rover|drive|slip|truth|scene|add-rock|fault", "NAME|PATH"),
         help="simulation control: sim move-rover -dx -dy -dyaw | sim drive -v -w -seconds | "
              "sim slip -distance -heading -seed | sim truth | sim scene NAME|PATH | "
              "sim add-rock -x -y -radius -height | sim fault -device D -kind K")
def sim(ctx: Context, cfg: None) -> Any:
    req, app, world = ctx.request, ctx.app, ctx.app.world
    if not req.positional or req.positional[0].lower() not in VERBS:
        raise ProtocolError("E_ARG", f"sim takes one of {', '.join(VERBS)}")
    verb = req.positional[0].lower()
    extra = req.positional[1:]
    if extra and verb != "scene" or len(extra) > 1:
        raise ProtocolError("E_ARG", f"sim {verb} takes options, not '{extra[0][:40]}'")
    opts = apply_options(f"sim {verb}", VERBS[verb](), req.options)
    if verb == "move-rover":
        assert isinstance(opts, SimMoveRoverConfig)
        world.move_rover(opts.dx, opts.dy, opts.dyaw)
        app.travel.forget()  # carried off: no navigate's map holds the ground it stands on now
        return _truth(world)
    if verb == "drive":
        assert isinstance(opts, SimDriveConfig)
        if world.driving:
            raise ProtocolError("E_BUSY", "the rover is already driving (navigate -auto or another sim drive); "
                                          "wait for it")
        v = world.drive_model.speed if opts.v is None else opts.v
        return _drive(app, world, v, opts.w, opts.seconds)
    if verb == "slip":
        assert isinstance(opts, SimSlipConfig)
        world.set_slip(opts.distance, opts.heading, opts.seed)
        return {"slip_distance": Fixed(opts.distance, 4), "slip_heading": Fixed(opts.heading, 3), "seed": opts.seed}
    if verb == "truth":
        return _truth(world)
    if verb == "add-rock":
        assert isinstance(opts, SimAddRockConfig)
        try:
            rock = world.add_rock(opts.x, opts.y, opts.radius, opts.height)
        except ValueError as exc:
            raise ProtocolError("E_ARG", str(exc)) from None
        return {"x": Fixed(rock["x"], 3), "y": Fixed(rock["y"], 3), "radius": Fixed(opts.radius, 3),
                "height": Fixed(rock["height"], 3), "rocks": len(world.rocks())}
    if verb == "scene":
        if not extra:
            return {"scene": world.scene_name}
        if app.jobs.current is not None:
            raise ProtocolError("E_BUSY", "the scene cannot change while a job runs")
        if world.driving:
            raise ProtocolError("E_BUSY", "the scene cannot change while the rover drives")
        try:
            world.load_scene(extra[0])
        except (OSError, KeyError, ValueError, TypeError) as exc:
            raise ProtocolError("E_ARG", f"{exc}; give a name from config/scenes/ or the path of a scene "
                                         ".yaml file") from None
        app.travel.forget()
        return {"scene": world.scene_name, **_truth(world)}
    assert isinstance(opts, SimFaultConfig)
    kind = None if opts.kind == "none" else opts.kind
    if kind is not None and kind not in FAULT_KINDS[opts.device]:
        raise ProtocolError("E_ARG", f"-kind for {opts.device} is one of none, {', '.join(FAULT_KINDS[opts.device])}")
    dev = app.devices.devices.get(opts.device)
    if dev is None or Capability.FAULTS not in dev.capabilities:
        raise ProtocolError("E_STATE", f"{opts.device} is not an open simulated device")
    dev.inject_fault(kind)
    return {"device": opts.device, "fault": kind or "none"}


async def _drive(app: Any, world: Any, v: float, w: float, seconds: float) -> dict[str, Any]:
    """Drive off the event loop: ``seconds`` of simulated time take ``seconds / sim.time_scale``
    wall seconds, while the server answers everyone else. Ends early if the server quits."""
    def stop() -> bool:
        return bool(app.quitting or app.stopping.is_set())

    done = await asyncio.to_thread(world.drive, v, w, seconds, stop)
    return {**_truth(world), "seconds": Fixed(done["seconds"], 3), "distance": Fixed(done["distance"], 4)}
