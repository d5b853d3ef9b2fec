"""Simulation control (only when backends are simulated): move the rover, read the truth,
change the scene, inject device faults. For tests and demos; a real rover has none of it."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from drivers.registry import Capability, fault_kinds

from ..app import Context
from ..config import ModuleConfig, param
from ..protocol import Fixed, ProtocolError
from ..table import ALWAYS, apply_options, command

FAULT_KINDS = fault_kinds()  # declared once, by each device's simulator backend


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
class NoOptions(ModuleConfig):
    module: ClassVar[str] = "sim_none"


VERBS: dict[str, type[ModuleConfig]] = {
    "move-rover": SimMoveRoverConfig,
    "truth": NoOptions,
    "scene": NoOptions,
    "fault": SimFaultConfig,
}


def _truth(world: Any) -> dict[str, Any]:
    t = world.truth()
    return {"x": Fixed(t["x"], 4), "y": Fixed(t["y"], 4), "z": Fixed(t["z"], 4), "heading": Fixed(t["heading"], 3),
            "pan": Fixed(t["pan"], 3), "tilt": Fixed(t["tilt"], 3)}


@command("sim", klass=ALWAYS, raw=True, sim_only=True, positional=("move-rover|truth|scene|fault", "NAME"),
         help="simulation control: sim move-rover -dx -dy -dyaw | sim truth | sim scene NAME | "
              "sim fault -device D -kind K")
def sim(ctx: Context, cfg: None) -> dict[str, Any]:
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
        return _truth(world)
    if verb == "truth":
        return _truth(world)
    if verb == "scene":
        if not extra:
            return {"scene": world.scene_name}
        if app.jobs.current is not None:
            raise ProtocolError("E_BUSY", "the scene cannot change while a job runs")
        try:
            world.load_scene(extra[0])
        except (FileNotFoundError, KeyError, ValueError) as exc:
            raise ProtocolError("E_ARG", f"no scene '{extra[0][:40]}' ({exc}); scenes are in config/scenes/") from None
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
