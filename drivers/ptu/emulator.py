"""A PTU-D46 on the other end of a pseudo-terminal: the simulated PTU speaks the real protocol.

The ``sim`` backend runs the very client that drives a real PTU over RS232 against this
emulator, so every byte the server would send to the hardware is exercised in simulation. The
emulator behaves like a freshly powered D46: verbose feedback, echo on and a banner; the
factory resolution (185.1428 arc-seconds per position) and axis bounds; trapezoidal moves at
its speed, acceleration and base speed (:mod:`rvs_params.motion`) in simulated time
(``time_scale`` simulated-to-wall ratio: 1 real time, 0.1 ten times faster, 0 instantly; or, given a ``clock``, on the simulated world's clock,
so PTU moves take their time on the same clock as the rover's drive and the ToF's frames); ``!`` errors for out-of-range positions and speeds;
``A`` answered when motion ends; a reset that runs each axis into its limits ("!T!T!P!P*").

Faults reproduce what goes wrong on a bench: ``silent`` (unpowered or wrong cable: reads,
never answers), ``garbage`` (the host at a wrong baud rate: every byte re-framed as a faster
UART sees it) and ``stall`` (moves accepted, the axes never turn, ``A`` never returns).

Flavours (:data:`FLAVOURS`) choose whose replies the emulator prints: ``manual`` answers as the
PTU-D46 manual prints (axis bounds 3090/-3090 and 604/-907, "positions/sec"); ``field`` as the
recorded real units in shared/realdata/ptu/PTU-D46_reply_reference.md (bounds a few counts off,
3091/-3090 and 601/-903, per-axis speed ceilings of 600 and 4002 "pos/sec", "Motor speed cannot
be less than 31 pos/sec", a lower-case axis in verbose positions, the real V and O wording). The
client must drive both: a driver tested only against the manual breaks on the first real unit.
"""

from __future__ import annotations

import math
import os
import re
import select
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from drivers.ptu.protocol import (
    D46_DEFAULT_ACCEL,
    D46_DEFAULT_BASE,
    D46_DEFAULT_SPEED,
    D46_LIMITS,
    D46_MAX_ACCEL,
    D46_RESOLUTION_ARCSEC,
    D46_SPEED_BOUNDS,
    pos_to_deg,
)
from rvs_params.motion import Profile, stop_distance

FAULTS = (None, "silent", "garbage", "stall")
FIRMWARE = "PTU-D46 emulator v2.14.0 (RVS simulated backend)"


@dataclass(frozen=True)
class Flavour:
    """Whose wording and bounds the emulator answers with (see the module docstring)."""

    name: str
    limits: dict[str, tuple[int, int]]
    speed_bounds: dict[str, tuple[int, int]]  # per axis (PL, PU)
    speed_unit: str  # "positions/sec" (manual) or "pos/sec" (recorded units)
    firmware: str
    speed_floor_error: str  # PS below PL; {name} and {lo} and {unit} are filled in
    lower_case_position: bool  # "Current pan position is 0" (the manual's FV example) vs "Pan"
    power_format: str  # the verbose O reply; {v} and {f} are filled in


FLAVOURS: dict[str, Flavour] = {
    "manual": Flavour(
        "manual", dict(D46_LIMITS), {"pan": D46_SPEED_BOUNDS, "tilt": D46_SPEED_BOUNDS}, "positions/sec",
        FIRMWARE, "{name} speed cannot be less than {lo} {unit}", False, "Input {v:.1f} VDC @ {f:.0f} degF",
    ),
    "field": Flavour(
        "field", {"pan": (-3090, 3091), "tilt": (-903, 601)}, {"pan": (31, 600), "tilt": (31, 4002)}, "pos/sec",
        "Pan-Tilt Controller v2.12.1d1(C14/E), (C)2003 Directed Perception, Inc., All Rights Reserved",
        "Motor speed cannot be less than {lo} {unit}", True, "Input {v:.0f} VDC @ {f:.0f} degF",
    ),
}
_TOKEN = re.compile(r"^([A-Z?]+)(.*)$")
_INT = re.compile(r"^[-+]?\d+$")


def open_pty() -> tuple[int, int, str]:
    """A raw pseudo-terminal pair: (master fd, slave fd, slave path).

    The slave is put in raw mode at once so that nothing written before a client opens it (the
    banner) is echoed back by the line discipline; keeping the slave fd open keeps the master
    readable while no client is attached.
    """
    master, slave = os.openpty()
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


def misframe(data: bytes, ratio: float = 4.0) -> bytes:
    """What a UART reading ``ratio`` times faster than the sender sees (8N1 both ends).

    The sender's line is rebuilt bit cell by bit cell (idle high, start 0, 8 data bits LSB
    first, stop 1) and the receiver samples it at its own rate: one byte sent at 2400 baud and
    read at 9600 becomes a few bytes of 0x00/0x78/0x80/0xF8, as on a real bench.
    """
    cells: list[int] = []
    for b in data:
        cells += [0] + [(b >> i) & 1 for i in range(8)] + [1]
    n = len(cells)

    def level(t: float) -> int:
        i = int(t)
        return cells[i] if 0 <= i < n else 1

    step = 1.0 / ratio  # one receiver bit in sender bit cells
    out = bytearray()
    t = 0.0
    while t < n:
        if level(t) == 1:
            t += step / 8  # hunting for a start edge at 8x oversampling
            continue
        value = sum(level(t + (k + 1.5) * step) << k for k in range(8))
        out.append(value)
        t += 9.5 * step  # resynchronise after the (possibly missing) stop bit
    return bytes(out)


@dataclass
class _Axis:
    name: str  # "Pan" / "Tilt", as the D46 spells them in verbose replies
    lo: int
    hi: int
    speed: int = D46_DEFAULT_SPEED
    accel: int = D46_DEFAULT_ACCEL
    speed_lo: int = D46_SPEED_BOUNDS[0]
    speed_hi: int = D46_SPEED_BOUNDS[1]
    base: int = D46_DEFAULT_BASE
    pos: float = 0.0
    vel: float = 0.0
    target: int = 0
    profile: Profile | None = None
    pending: int | None = None  # slaved mode: target waiting for A
    move_t0: float = 0.0
    move_p0: float = 0.0
    log: list[dict] = field(default_factory=list)

    @property
    def position(self) -> int:
        return int(math.floor(self.pos + 0.5))

    def moving(self) -> bool:
        return self.profile is not None or self.target != self.position


HOOK_BYTES = 1 << 18  # rx and tx keep the last 256 KiB or so
HOOK_ITEMS = 2_000  # commands and each axis's move log keep the last two thousand or so


def _bounded(seq: list | bytearray, keep: int) -> None:
    """Trim a test hook to its last ``keep`` items once it holds twice that (amortised O(1)): a
    simulated server that runs for days must not keep every byte it ever heard."""
    if len(seq) > 2 * keep:
        del seq[: len(seq) - keep]


class PtuEmulator:
    """A PTU-D46 serving one pty master fd from a background thread.

    Test hooks: ``commands`` (every command token received, as sent), ``rx`` (all bytes
    received), ``moves`` (completed moves with simulated start, end and duration; these three
    and ``tx`` keep only their recent part past ``HOOK_ITEMS`` / ``HOOK_BYTES``),
    ``sim_time``, ``prefix_next_reply`` (bytes slipped in front of the next reply: an async
    ``!P``, junk), ``write_raw`` (bytes on the line now: stale replies), ``chunk`` (write
    replies this many bytes at a time, to split them across the client's reads).
    """

    def __init__(
        self,
        fd: int,
        *,
        time_scale: float = 1.0,
        on_position: Callable[[float, float], None] | None = None,
        on_target: Callable[[float, float], None] | None = None,
        eol: bytes = b"\r\n",
        banner: bool = True,
        resolution: float = D46_RESOLUTION_ARCSEC,
        limits: dict[str, tuple[int, int]] | None = None,
        speed: int = D46_DEFAULT_SPEED,
        acceleration: int = D46_DEFAULT_ACCEL,
        base_speed: int = D46_DEFAULT_BASE,
        fault: str | None = None,
        chunk: int | None = None,
        tick: float = 0.01,
        garbage_ratio: float = 4.0,
        supply_v: float = 30.0,
        temperature_f: float = 86.0,
        flavour: str | Flavour = "manual",
        clock: Any = None,
    ) -> None:
        if time_scale < 0:
            raise ValueError("time_scale must be >= 0 (0 = instant moves)")
        if isinstance(flavour, str):
            if flavour not in FLAVOURS:
                raise ValueError(f"unknown PTU flavour {flavour!r}; use one of {', '.join(FLAVOURS)}")
            flavour = FLAVOURS[flavour]
        self.flavour = flavour
        lim = dict(flavour.limits, **(limits or {}))
        self.fd = fd
        self.on_position = on_position
        self.on_target = on_target  # told (pan, tilt) in degrees where a move will stop, as it starts
        self.eol = eol
        self.banner = banner
        self.resolution = float(resolution)
        self.chunk = chunk
        self.tick = tick
        self.garbage_ratio = garbage_ratio
        self.supply_v = supply_v
        self.temperature_f = temperature_f
        self.echo = True
        self.verbose = True
        self.limits_enforced = True
        self.slaved = False
        self.axes = {key: self._new_axis(name, lim[name.lower()], speed, acceleration, base_speed)
                     for key, name in (("P", "Pan"), ("T", "Tilt"))}
        self.commands: list[str] = []
        self.rx = bytearray()
        self.tx = bytearray()
        self._fault = self._check_fault(fault)
        self._lock = threading.RLock()
        self._cond = threading.Condition(self._lock)
        self._inbuf = bytearray()
        self._deferred: list[str] = []
        self._awaits = 0
        self._reset_phases: list[tuple[str, int, bytes]] | None = None
        self._prefix = bytearray()
        self._scale = float(time_scale)
        # A drivers.sim.clock.SimClock: when given, simulated time is the clock's (time_scale
        # is then ignored until set explicitly), and an instant move still moves the clock on.
        self._clock = clock
        self._sim_t = clock.now() if clock is not None else 0.0
        self._sim_ref = 0.0
        self._wall_ref = time.monotonic()
        self._last_reported: tuple[float, float] | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _new_axis(self, name: str, bounds: tuple[int, int], speed: int, accel: int, base: int) -> _Axis:
        """An axis with the flavour's speed bounds; a power-up speed above the unit's ceiling
        comes up at the ceiling, as a unit whose PU was lowered keeps its speed under it."""
        lo, hi = self.flavour.speed_bounds[name.lower()]
        return _Axis(name, *bounds, speed=min(max(speed, lo), hi), accel=accel, speed_lo=lo, speed_hi=hi, base=base)

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> PtuEmulator:
        if self._thread is not None:
            return self
        if self.banner:
            self._send(
                f"{self.flavour.firmware}, {self.resolution:.4f} seconds arc per position".encode() + self.eol
                + b"Initializing..." + self.eol + b"*" + self.eol
            )
        self._report_position()
        self._thread = threading.Thread(target=self._run, name="ptu-emulator", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # -- controls and test hooks ---------------------------------------------------------------
    @property
    def fault(self) -> str | None:
        return self._fault

    def inject_fault(self, kind: str | None) -> None:
        with self._lock:
            self._fault = self._check_fault(kind)

    @property
    def time_scale(self) -> float:
        """Wall seconds per simulated second (0: instant), the clock's when following one."""
        return self._wall_per_sim()

    @time_scale.setter
    def time_scale(self, value: float) -> None:
        if value < 0:
            raise ValueError("time_scale must be >= 0")
        with self._lock:
            self._advance()
            self._clock = None  # an explicit scale: the emulator keeps its own time from here
            self._sim_ref, self._wall_ref, self._scale = self._sim_t, time.monotonic(), float(value)

    def _wall_per_sim(self) -> float:
        if self._clock is not None:
            scale = self._clock.scale
            return 1.0 / scale if scale > 0 else 0.0
        return self._scale

    @property
    def sim_time(self) -> float:
        with self._lock:
            self._advance()
            return self._sim_t

    @property
    def moves(self) -> list[dict]:
        with self._lock:
            return sorted(self.axes["P"].log + self.axes["T"].log, key=lambda m: m["t_end"])

    def positions(self) -> tuple[int, int]:
        with self._lock:
            self._advance()
            return self.axes["P"].position, self.axes["T"].position

    def position_deg(self) -> tuple[float, float]:
        with self._lock:
            self._advance()
            return (pos_to_deg(self.axes["P"].pos, self.resolution), pos_to_deg(self.axes["T"].pos, self.resolution))

    def prefix_next_reply(self, data: bytes) -> None:
        with self._lock:
            self._prefix.extend(data)

    def write_raw(self, data: bytes) -> None:
        with self._lock:
            self._write(data)

    def wait_for(self, predicate: Callable[[PtuEmulator], bool], timeout: float = 2.0) -> bool:
        """Block until ``predicate(self)`` holds (checked on every emulator step)."""
        with self._cond:
            return self._cond.wait_for(lambda: predicate(self), timeout=timeout)

    # -- the loop ----------------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                busy = self._busy() and self._wall_per_sim() > 0
            try:
                ready, _, _ = select.select([self.fd], [], [], self.tick if busy else 0.05)
                data = os.read(self.fd, 4096) if ready else b""
            except OSError:  # fd closed under us, or no slave attached: keep simulating
                if self._stop.is_set():
                    break
                data = b""
                time.sleep(self.tick)
            with self._cond:
                if data:
                    self._receive(data)
                self._advance()
                self._answer_awaits()
                self._cond.notify_all()
            self._report_position()

    def _receive(self, data: bytes) -> None:
        self.rx.extend(data)
        _bounded(self.rx, HOOK_BYTES)
        if self._fault == "silent":
            return
        if self.echo:
            self._send(data, prefix=False)
        self._inbuf.extend(data)
        text = self._inbuf.decode("ascii", "replace")
        *tokens, rest = re.split(r"[ \r\n\t]", text)
        self._inbuf = bytearray(rest.encode("ascii", "replace"))
        for token in tokens:
            if token:
                self._deferred.append(token)
        self._run_deferred()

    def _run_deferred(self) -> None:
        # A resetting D46 is busy: commands wait in its buffer until the reset ends.
        while self._deferred and self._reset_phases is None:
            token = self._deferred.pop(0)
            self.commands.append(token)
            _bounded(self.commands, HOOK_ITEMS)
            self._advance()
            self._execute(token.upper())
            self._advance()

    # -- simulated time and motion -------------------------------------------------------------
    def _horizon(self) -> float:
        if self._clock is not None:
            return self._clock.now() if self._clock.scale > 0 else math.inf
        if self._scale > 0:
            return self._sim_ref + (time.monotonic() - self._wall_ref) / self._scale
        return math.inf

    def _advance(self) -> None:
        if self._clock is not None and not self._busy():
            # Idle: the world's time went on without the PTU (the rover drove); a move
            # starts from the clock's now, not from where the last one ended.
            self._sim_t = max(self._sim_t, self._clock.now())
        horizon = self._horizon()
        while True:
            ends = [ax.profile.end for ax in self.axes.values() if ax.profile is not None]
            if not ends or min(ends) > horizon:
                break
            te = min(ends)
            self._sim_t = max(self._sim_t, te)
            for ax in self.axes.values():
                if ax.profile is not None and ax.profile.end <= te:
                    self._finish(ax, te)
            self._step_reset()
        if math.isfinite(horizon):
            self._sim_t = max(self._sim_t, horizon)
            for ax in self.axes.values():
                if ax.profile is not None:
                    ax.pos, ax.vel = ax.profile.at(self._sim_t)

    def _waited(self) -> None:
        """On an instant clock, a reply that waited for the axes (an await, a reset) moves the
        world's clock on to where they stopped: the caller's wait took that long. A move nobody
        awaits leaves the clock alone, so that a rover driving on meanwhile overlaps it, as the
        mast slews while the wheels turn; its time still counts from its start, and the next
        await that finds it ended sooner costs nothing."""
        if self._clock is not None and not math.isfinite(self._horizon()):
            self._clock.advance_to(self._sim_t, "ptu moves")

    def _finish(self, ax: _Axis, t: float) -> None:
        ax.pos, ax.vel, ax.profile = float(ax.target), 0.0, None
        ax.log.append({
            "axis": ax.name.lower(), "from": ax.move_p0, "to": ax.target,
            "t_start": ax.move_t0, "t_end": t, "duration": t - ax.move_t0,
        })
        _bounded(ax.log, HOOK_ITEMS)

    def _move(self, ax: _Axis, target: int, new_move: bool = True) -> None:
        if new_move or ax.profile is None:
            ax.move_t0, ax.move_p0 = self._sim_t, ax.pos
        ax.target = target
        if self._fault == "stall":
            return  # accepted, but the axis never turns
        ax.profile = Profile.start(self._sim_t, ax.pos, ax.vel, target, ax.speed, ax.accel, ax.base)
        if self.on_target is not None:
            self.on_target(pos_to_deg(self.axes["P"].target, self.resolution),
                           pos_to_deg(self.axes["T"].target, self.resolution))

    def _busy(self) -> bool:
        return self._reset_phases is not None or any(ax.moving() for ax in self.axes.values())

    def _answer_awaits(self) -> None:
        while self._awaits and not self._busy():
            self._awaits -= 1
            self._waited()
            self._ack()

    def _start_reset(self, which: str) -> None:
        phases: list[tuple[str, int, bytes]] = []
        if "T" in which:
            phases += [("T", self.axes["T"].hi, b"!T"), ("T", self.axes["T"].lo, b"!T")]
        if "P" in which:
            phases += [("P", self.axes["P"].hi, b"!P"), ("P", self.axes["P"].lo, b"!P")]
        phases += [(a, 0, b"") for a in which]
        self._reset_phases = phases
        self._begin_phase()

    def _begin_phase(self) -> None:
        assert self._reset_phases is not None
        axis, target, _ = self._reset_phases[0]
        self._move(self.axes[axis], target)

    def _step_reset(self) -> None:
        while self._reset_phases:
            axis, _, token = self._reset_phases[0]
            if self.axes[axis].moving():
                return
            self._reset_phases.pop(0)
            if token:
                self._send(token)
            if self._reset_phases:
                self._begin_phase()
            else:
                self._reset_phases = None
                self._waited()
                self._ack()
                self._run_deferred()
                return

    def _report_position(self) -> None:
        if self.on_position is None:
            return
        with self._lock:
            pan = pos_to_deg(self.axes["P"].pos, self.resolution)
            tilt = pos_to_deg(self.axes["T"].pos, self.resolution)
            if self._last_reported == (pan, tilt):
                return
            self._last_reported = (pan, tilt)
        self.on_position(pan, tilt)

    # -- the command set ---------------------------------------------------------------------
    def _execute(self, token: str) -> None:
        m = _TOKEN.match(token)
        if not m:
            return self._error("Illegal command")
        word, arg = m.groups()
        if arg and not _INT.match(arg):
            return self._error("Illegal argument")
        value = int(arg) if arg else None
        if len(word) == 2 and word[0] in "PT" and word[1] in "PORNXSAULBD":
            return self._axis_command(self.axes[word[0]], word[1], value)
        handler = self._SIMPLE.get(word)
        if handler is None:
            return self._error("Illegal command")
        if value is not None:
            return self._error("Illegal argument")
        handler(self)

    def _axis_command(self, ax: _Axis, op: str, value: int | None) -> None:
        name = ax.name
        unit = self.flavour.speed_unit
        if op in "PO":
            if value is None:
                said = name.lower() if self.flavour.lower_case_position else name
                return self._result(f"Current {said} position is {ax.position}", ax.position)
            target = value if op == "P" else ax.position + value
            if self.limits_enforced and target > ax.hi:
                return self._error(f"Maximum allowable {name} position is {ax.hi}")
            if self.limits_enforced and target < ax.lo:
                return self._error(f"Minimum allowable {name} position is {ax.lo}")
            if self.slaved:
                ax.pending = target
            else:
                self._move(ax, target, new_move=not ax.moving())
            return self._ack()
        if op == "D" and value is None:
            return self._result(f"Desired {name} position is {ax.target}", ax.target)
        if value is None:
            queries = {
                "R": (f"{self.resolution:.4f} seconds arc per {name} position", f"{self.resolution:.4f}"),
                "N": (f"Minimum {name} position is {ax.lo}", ax.lo),
                "X": (f"Maximum {name} position is {ax.hi}", ax.hi),
                "S": (f"Desired {name} speed is {ax.speed} {unit}", ax.speed),
                "A": (f"{name} acceleration is {ax.accel} {unit}^2", ax.accel),
                "U": (f"Maximum {name} speed is {ax.speed_hi} {unit}", ax.speed_hi),
                "L": (f"Minimum {name} speed is {ax.speed_lo} {unit}", ax.speed_lo),
                "B": (f"Current {name} base speed is {ax.base} {unit}", ax.base),
            }
            verbose, terse = queries[op]
            return self._result(verbose, terse)
        if op == "S":
            if value > ax.speed_hi:
                return self._error(f"{name} speed cannot exceed {ax.speed_hi} {unit}")
            if value < ax.speed_lo:
                return self._error(self.flavour.speed_floor_error.format(name=name, lo=ax.speed_lo, unit=unit))
            ax.speed = value
            if ax.profile is not None:  # speed changes take effect on the fly
                self._move(ax, ax.target, new_move=False)
            return self._ack()
        if op == "A":
            if not 1 <= value <= D46_MAX_ACCEL:
                return self._error(f"{name} acceleration must be 1 to {D46_MAX_ACCEL} {unit}^2")
            ax.accel = value
            return self._ack()
        if op == "U":
            if value <= ax.speed_lo:
                return self._error(f"Maximum {name} speed must exceed {ax.speed_lo} {unit}")
            ax.speed_hi = value
            return self._ack()
        if op == "L":
            if value < self.flavour.speed_bounds[name.lower()][0] or value >= ax.speed_hi:
                floor = self.flavour.speed_bounds[name.lower()][0]
                return self._error(f"Motor speed cannot be less than {floor} pos/sec")
            ax.speed_lo = value
            return self._ack()
        if op == "B":
            ax.base = value
            return self._ack()
        return self._error("Illegal argument")

    def _cmd_await(self) -> None:
        if self.slaved:
            for ax in self.axes.values():
                if ax.pending is not None:
                    self._move(ax, ax.pending)
                    ax.pending = None
            self._advance()
        if self._busy():
            self._awaits += 1
        else:
            self._waited()
            self._ack()

    def _cmd_halt(self, which: str = "PT") -> None:
        for key in which:
            ax = self.axes[key]
            ax.pending = None
            if ax.profile is None:
                ax.target = ax.position  # a stalled axis gives up its target
                continue
            stop = ax.pos + math.copysign(stop_distance(ax.vel, ax.accel, ax.base), ax.vel)
            self._move(ax, int(math.floor(stop + 0.5)), new_move=False)
        self._ack()

    def _set(self, **attrs: object) -> None:
        for key, value in attrs.items():
            setattr(self, key, value)
        self._ack()

    def _factory_defaults(self) -> None:
        for ax in self.axes.values():
            lo, hi = self.flavour.speed_bounds[ax.name.lower()]
            ax.speed, ax.accel, ax.speed_lo, ax.speed_hi = min(D46_DEFAULT_SPEED, hi), D46_DEFAULT_ACCEL, lo, hi
            ax.base = D46_DEFAULT_BASE
        self._ack()

    def _help(self) -> None:
        self._result("Commands: PP TP PO TO PD TD PR TR PN PX TN TX PS TS PA TA PU TU PL TL PB TB "
                     "A H HP HT R RP RT I S CI CV C LE LD L FT FV F EE ED E O V DR DS DF ?", "")

    _SIMPLE: dict[str, Callable[[PtuEmulator], None]] = {
        "A": _cmd_await,
        "H": _cmd_halt,
        "HP": lambda self: self._cmd_halt("P"),
        "HT": lambda self: self._cmd_halt("T"),
        "R": lambda self: self._start_reset("PT"),
        "RP": lambda self: self._start_reset("P"),
        "RT": lambda self: self._start_reset("T"),
        "FT": lambda self: self._set(verbose=False),
        "FV": lambda self: self._set(verbose=True),
        "F": lambda self: self._result(f"ASCII {'verbose' if self.verbose else 'terse'} mode",
                                       "VERBOSE" if self.verbose else "TERSE"),
        "EE": lambda self: self._set(echo=True),
        "ED": lambda self: self._set(echo=False),
        "E": lambda self: self._result(f"Echoing {'ON' if self.echo else 'OFF'}", "ON" if self.echo else "OFF"),
        "I": lambda self: self._set(slaved=False),
        "S": lambda self: self._set(slaved=True),
        "CI": lambda self: self._ack(),
        "CV": lambda self: self._error("Pure velocity mode is not emulated"),
        "C": lambda self: self._result("Independent speed mode", "I"),
        "LE": lambda self: self._set(limits_enforced=True),
        "LD": lambda self: self._set(limits_enforced=False),
        "L": lambda self: self._result(f"Limit bounds are {'ENABLED' if self.limits_enforced else 'DISABLED'}",
                                       "E" if self.limits_enforced else "D"),
        "O": lambda self: self._result(self.flavour.power_format.format(v=self.supply_v, f=self.temperature_f),
                                       f"{self.supply_v:.1f} VDC {self.temperature_f:.0f} degF"),
        "V": lambda self: self._result(self.flavour.firmware, self.flavour.firmware),
        "DS": lambda self: self._ack(),
        "DR": lambda self: self._ack(),
        "DF": _factory_defaults,
        "?": _help,
    }

    # -- output ------------------------------------------------------------------------------
    def _ack(self) -> None:
        self._send(b"*" + self.eol)

    def _result(self, verbose: str, terse: object) -> None:
        text = verbose if self.verbose else str(terse)
        self._send(f"* {text}".encode("ascii") + self.eol)

    def _error(self, message: str) -> None:
        self._send(f"! {message}".encode("ascii") + self.eol)

    def _send(self, data: bytes, prefix: bool = True) -> None:
        if self._fault == "silent":
            return
        if prefix and self._prefix:
            data = bytes(self._prefix) + data
            self._prefix.clear()
        if self._fault == "garbage":
            data = misframe(data, self.garbage_ratio)
        self._write(data)

    def _write(self, data: bytes) -> None:
        self.tx.extend(data)
        _bounded(self.tx, HOOK_BYTES)
        step = self.chunk or len(data) or 1
        try:
            for i in range(0, len(data), step):
                os.write(self.fd, data[i : i + step])
                if self.chunk:
                    time.sleep(0.001)
        except OSError:
            pass  # the pty went away; the emulator is being stopped

    @staticmethod
    def _check_fault(kind: str | None) -> str | None:
        if kind in ("", "none", "None"):
            kind = None
        if kind not in FAULTS:
            raise ValueError(f"unknown PTU fault {kind!r}; use one of silent, garbage, stall or None")
        return kind
