"""The PTU-D46 client over pyserial: one exchange at a time, degrees in, degrees out.

The port is any pyserial URL (``/dev/ttyUSB0``, a pty path, ``loop://``, ``socket://``), so
the same code drives the real unit and the emulator. At open the unit is put in a known state
whatever it was left in (terse feedback, echo off, independent speed control, immediate
position execution) and its resolution, axis bounds and speed bounds are read back: positions are
computed from what the unit says, never from a hard-coded constant. Targets are checked against
those bounds before anything is sent. Real units differ from the manual by a few counts (3091 where
the manual says 3090) and in wording ("pos/sec" for "positions/sec"): every number is read from
the reply by position, not by matching the manual's sentence, and a refusal that states a bound
updates the bound the client believes (see shared/realdata/ptu/PTU-D46_reply_reference.md).

Every exchange holds ``lock`` (re-entrant, so a move holds it across its PP/TP/A/PP/TP
sequence). A move's await can be cut short by a ``cancel`` callable/Event or by ``halt()``
from another thread: the waiting thread sends ``H`` itself, so a halt never waits for the
move it stops. Nor does it wait for the axes to decelerate (half a second at the default speed
and acceleration): once the ``H`` is acknowledged the wait ends, and the ``A``'s own reply,
which comes when the axes stand, is read by the next command before it is sent (as an
interrupted reset's is), which also reads back where they stopped.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable
from typing import Any

import serial

from drivers.base import Cancel, DeviceError, DeviceInterrupted
from drivers.ptu.protocol import (
    Reply,
    ReplyParser,
    deg_to_pos,
    encode_command,
    parse_bound,
    parse_power,
    pos_to_deg,
)

DEVICE = "ptu"
_READ_SLICE = 0.02  # seconds per serial read: how often a wait looks at cancel and deadlines
AXES = ("pan", "tilt")



class ReplyTimeout(DeviceError):
    """No (readable) reply in time: the line is dead, unpowered or at the wrong baud rate."""

    def __init__(self, message: str) -> None:
        super().__init__(DEVICE, message)


class MoveInterrupted(DeviceInterrupted):
    """A move stopped early by ``halt()`` or its ``cancel``; ``position`` is where it stopped
    (``halt()``), or where the axes were when a ``cancel``'s halt was acknowledged: they
    decelerate a little further, and the client's next command waits for that and reads the
    position again."""

    def __init__(self, message: str, position: tuple[float, float] | None) -> None:
        super().__init__(DEVICE, message)
        self.position = position


def _stop_fn(cancel: Cancel) -> Callable[[], bool]:
    if cancel is None:
        return lambda: False
    if isinstance(cancel, threading.Event):
        return cancel.is_set
    return cancel


class PtuClient:
    """One PTU-D46 on one serial port."""

    def __init__(
        self,
        port: str,
        baudrate: int = 9600,
        *,
        timeout: float = 2.0,
        move_timeout: float = 30.0,
        reset_timeout: float = 60.0,
        speed: int | None = None,
        acceleration: int | None = None,
    ) -> None:
        self.port = str(port)
        self.baudrate = int(baudrate)
        self.timeout = float(timeout)
        self.move_timeout = float(move_timeout)
        self.reset_timeout = float(reset_timeout)
        self.speed = speed
        self.acceleration = acceleration
        self.lock = threading.RLock()
        self._ser: Any = None
        self._parser = ReplyParser()
        self._replies: collections.deque[Reply] = collections.deque()
        self._resync = False
        self._halt = threading.Event()
        # monotonic deadline of an R whose wait was interrupted: the unit goes on resetting and
        # answers nothing else until it ends, so the next command first waits for its reply
        self._reset_until: float | None = None
        # monotonic deadline of an A whose wait a halt cut short: its reply comes when the axes
        # stand, so the next command first reads it (and where they stopped)
        self._await_until: float | None = None
        self.resolution: dict[str, float] = {}
        self.bounds: dict[str, tuple[int, int]] = {}
        # (PL, PU) per axis; an axis whose unit does not answer PL/PU (older firmware) has none
        self.speed_bounds: dict[str, tuple[int, int]] = {}
        self._state_lock = threading.Lock()
        self._state: dict[str, Any] = {
            "open": False, "pan_deg": None, "tilt_deg": None, "pan_pos": None, "tilt_pos": None,
            "target_pan_deg": None, "target_tilt_deg": None, "moving": False, "limit_hits": 0,
            "last_async": None, "speed_clamped": None,
        }

    # -- open / close --------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._ser is not None

    def open(self) -> None:
        with self.lock:
            if self._ser is not None:
                return
            try:
                self._ser = serial.serial_for_url(
                    self.port, baudrate=self.baudrate, timeout=_READ_SLICE, write_timeout=self.timeout
                )
            except (serial.SerialException, ValueError, OSError) as exc:
                raise DeviceError(
                    DEVICE,
                    f"cannot open serial port {self.port} at {self.baudrate} baud ({exc}); check that the "
                    "PTU's RS232 cable or USB adapter is plugged in, the port name (drivers.ptu.port, "
                    "e.g. ls /dev/ttyUSB* /dev/ttyS*) and that you may use it (group dialout)",
                ) from exc
            try:
                self._handshake()
            except BaseException:
                self.close()
                raise
            self._set_state(open=True)

    def close(self) -> None:
        with self.lock:
            if self._ser is not None and self._await_until is not None:
                try:  # a reopened line must not take the halted move's late reply for its own
                    self._finish_halt()
                except DeviceError:
                    pass
            ser, self._ser = self._ser, None
            if ser is not None:
                try:
                    ser.close()
                except Exception:  # noqa: BLE001 - closing a dead port must not fail a reinit
                    pass
            self._set_state(open=False, moving=False)

    def _handshake(self) -> None:
        # A lone delimiter ends any half command left in the unit's buffer; whatever it says
        # about that (and the power-up banner) is drained before the first real command.
        self._write(b" ")
        self._drain(0.05)
        for cmd in ("FT", "ED", "CI", "I"):
            self.command(cmd)
        for axis, letter in (("pan", "P"), ("tilt", "T")):
            res = self.query_number(f"{letter}R")
            if res <= 0:
                raise DeviceError(DEVICE, f"the PTU reported a {axis} resolution of {res}; expected > 0")
            self.resolution[axis] = res
        for axis, letter in (("pan", "P"), ("tilt", "T")):
            lo, hi = int(self.query_number(f"{letter}N")), int(self.query_number(f"{letter}X"))
            self.bounds[axis] = (lo, hi)
        self._read_speed_bounds()
        if self.speed is not None:
            self.set_speed(*self._speed_within_bounds(self.speed))
        if self.acceleration is not None:
            self.set_acceleration(self.acceleration, self.acceleration)
        self.position()

    def _read_speed_bounds(self) -> None:
        """PL/PU and TL/TU, as the ROS flir_ptu driver reads them at init: a real unit's ceiling
        may be far below the manual's (600 pos/sec pan on a recorded unit, against 2902), and a
        configured speed above it would fail the open."""
        for axis, letter in (("pan", "P"), ("tilt", "T")):
            try:
                lo, hi = int(self.query_number(f"{letter}L")), int(self.query_number(f"{letter}U"))
            except ReplyTimeout:
                raise
            except DeviceError:
                continue  # refused: this firmware has no speed bounds to ask; the unit enforces its own
            self.speed_bounds[axis] = (lo, hi)

    def _speed_within_bounds(self, speed: float) -> tuple[int, int]:
        """The configured speed per axis, brought inside the unit's (PL, PU): one setting
        (drivers.ptu.speed) serves units with different ceilings; the snapshot says when it was cut."""
        out: list[int] = []
        notes: list[str] = []
        for axis in AXES:
            value = int(round(speed))
            lo, hi = self.speed_bounds.get(axis, (value, value))
            clamped = min(max(value, lo), hi)
            if clamped != value:
                notes.append(f"{axis} {value} -> {clamped} positions/s (unit bounds {lo}..{hi})")
            out.append(clamped)
        self._set_state(speed_clamped="; ".join(notes) or None)
        return out[0], out[1]

    def _learn_bound(self, text: str) -> None:
        """Believe a bound the unit states in a refusal over the one read earlier: limits differ
        between units by a few counts and a reset re-measures them."""
        bound = parse_bound(text)
        if bound is None:
            return
        table = self.bounds if bound.kind == "position" else self.speed_bounds
        axes = [bound.axis] if bound.axis else [a for a in AXES if a in table]
        for axis in axes:
            if axis not in table:
                continue
            lo, hi = table[axis]
            table[axis] = (lo, bound.value) if bound.side == "max" else (bound.value, hi)

    # -- one exchange ----------------------------------------------------------------------------
    def command(self, cmd: str, timeout: float | None = None, *, number: bool = False) -> Reply:
        """Send one command, return its ``*`` reply; a ``!`` reply raises with the unit's text."""
        with self.lock:
            self._send(cmd)
            reply = self._read_reply(cmd, self.timeout if timeout is None else timeout, number=number)
            assert reply is not None
            if not reply.ok:
                self._learn_bound(reply.text)
                raise DeviceError(DEVICE, f"the PTU refused {cmd}: {reply.text}")
            return reply

    def query_number(self, cmd: str) -> float:
        value = self.command(cmd, number=True).number()
        assert value is not None
        return value

    def raw(self, cmd: str, timeout: float | None = None) -> str:
        """Any command, its reply as the unit printed it ("* 583", "! Illegal command")."""
        with self.lock:
            self._send(cmd)
            reply = self._read_reply(cmd, self.timeout if timeout is None else timeout)
            assert reply is not None
            marker = "*" if reply.ok else "!"
            return f"{marker} {reply.text}" if reply.text else marker

    def _require(self) -> Any:
        if self._ser is None:
            raise DeviceError(DEVICE, f"serial port {self.port} is not open; open or reinit the PTU")
        return self._ser

    def _write(self, data: bytes) -> None:
        ser = self._require()
        try:
            ser.write(data)
        except (serial.SerialException, OSError) as exc:
            self._resync = True
            raise DeviceError(
                DEVICE, f"cannot write to {self.port} ({exc}); check cable, power and baud rate"
            ) from exc

    def _send(self, cmd: str, flush: bool = True) -> None:
        data = encode_command(cmd)
        ser = self._require()
        if self._reset_until is not None:
            self._finish_reset()
        if self._await_until is not None:
            self._finish_halt()
        if flush:
            if self._resync:  # a reply may still be on its way from a timed-out exchange
                self._drain(0.05)
                self._resync = False
            try:
                ser.reset_input_buffer()
            except (serial.SerialException, OSError):
                pass
            self._parser.reset()
            self._replies.clear()
        self._write(data)

    def _drain(self, seconds: float) -> None:
        ser = self._require()
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                ser.read(max(1, ser.in_waiting))
            except (serial.SerialException, OSError):
                return
        self._parser.reset()
        self._replies.clear()

    def _read_reply(
        self, cmd: str, timeout: float, *, number: bool = False, stop: Callable[[], bool] | None = None
    ) -> Reply | None:
        """The next reply; None if ``stop()`` turned true first; DeviceError on timeout."""
        ser = self._require()
        deadline = time.monotonic() + timeout
        ignored: list[str] = []
        while True:
            while self._replies:
                reply = self._replies.popleft()
                if number and reply.ok and reply.number() is None:
                    ignored.append(reply.line)  # garbled or foreign: keep waiting for the real one
                    continue
                return reply
            if stop is not None and stop():
                return None
            if time.monotonic() >= deadline:
                self._resync = True
                raise self._timeout_error(cmd, timeout, ignored)
            try:
                data = ser.read(max(1, ser.in_waiting))
            except (serial.SerialException, OSError) as exc:
                self._resync = True
                raise DeviceError(
                    DEVICE, f"reading {self.port} failed ({exc}); check cable, power and baud rate"
                ) from exc
            if data:
                self._replies.extend(self._parser.feed(data))
                if self._parser.async_events:
                    events, self._parser.async_events = self._parser.async_events, []
                    with self._state_lock:
                        self._state["limit_hits"] += len(events)
                        self._state["last_async"] = events[-1]

    def _timeout_error(self, cmd: str, timeout: float, ignored: list[str]) -> ReplyTimeout:
        where = f"{self.port} at {self.baudrate} baud"
        noise = self._parser.pending_noise()
        if noise:
            sample = bytes(self._parser.noise_sample[:12] or self._parser.buffer[:12])
            return ReplyTimeout(
                f"no valid reply to {cmd} within {timeout:g}s: received {noise} unreadable bytes "
                f"({sample!r}), the signature of a baud rate mismatch; check cable, power and baud rate "
                f"({where}; set drivers.ptu.baudrate to the unit's rate, 9600 from the factory)",
            )
        extra = f" (ignored {ignored[:3]!r})" if ignored else ""
        return ReplyTimeout(
            f"no reply to {cmd} within {timeout:g}s{extra}; check cable, power and baud rate ({where})"
        )

    # -- positions and limits --------------------------------------------------------------------
    def _require_setup(self) -> None:
        if not self.resolution or not self.bounds:
            raise DeviceError(DEVICE, "the PTU is not initialised (no resolution or limits); reinit it")

    def to_position(self, axis: str, deg: float) -> int:
        """Degrees to positions through the queried resolution, checked against the bounds."""
        self._require_setup()
        pos = deg_to_pos(deg, self.resolution[axis])
        lo, hi = self.bounds[axis]
        if not lo <= pos <= hi:
            lo_deg, hi_deg = (pos_to_deg(b, self.resolution[axis]) for b in (lo, hi))
            side = f"maximum {hi_deg:.2f} deg" if pos > hi else f"minimum {lo_deg:.2f} deg"
            raise DeviceError(
                DEVICE,
                f"{axis} {deg:g} deg is beyond the {axis} {side} (limits {lo_deg:.2f}..{hi_deg:.2f} deg, "
                f"positions {lo}..{hi})",
            )
        return pos

    def to_degrees(self, axis: str, pos: float) -> float:
        self._require_setup()
        return pos_to_deg(pos, self.resolution[axis])

    def limits(self) -> dict[str, dict[str, float]]:
        self._require_setup()
        out: dict[str, dict[str, float]] = {}
        for axis, (lo, hi) in self.bounds.items():
            out[axis] = {
                "min_deg": self.to_degrees(axis, lo), "max_deg": self.to_degrees(axis, hi),
                "min": lo, "max": hi, "resolution_arcsec": self.resolution[axis],
            }
            if axis in self.speed_bounds:
                out[axis]["speed_min"], out[axis]["speed_max"] = self.speed_bounds[axis]
        return out

    def position(self) -> tuple[float, float]:
        with self.lock:
            pan = int(self.query_number("PP"))
            tilt = int(self.query_number("TP"))
            pan_deg, tilt_deg = self.to_degrees("pan", pan), self.to_degrees("tilt", tilt)
            self._set_state(pan_pos=pan, tilt_pos=tilt, pan_deg=pan_deg, tilt_deg=tilt_deg)
            with self._state_lock:
                targets = (self._state["target_pan_deg"], self._state["target_tilt_deg"])
                moving = self._state["moving"]
            if moving and all(
                t is None or abs(t - p) < 1e-9 for t, p in zip(targets, (pan_deg, tilt_deg), strict=True)
            ):
                self._set_state(moving=False)
            return pan_deg, tilt_deg

    # -- motion --------------------------------------------------------------------------------
    def move(
        self,
        pan_deg: float | None,
        tilt_deg: float | None,
        wait: bool = True,
        *,
        cancel: Cancel = None,
        timeout: float | None = None,
    ) -> tuple[float, float]:
        """Absolute move (None keeps an axis); returns the position the unit then reports."""
        targets = {
            axis: self.to_position(axis, deg)
            for axis, deg in (("pan", pan_deg), ("tilt", tilt_deg))
            if deg is not None
        }
        with self.lock:
            for axis, pos in targets.items():
                self.command(f"{axis[0].upper()}P{pos}")
                self._set_state(**{f"target_{axis}_deg": self.to_degrees(axis, pos)}, moving=True)
            if wait:
                self.await_motion(cancel=cancel, timeout=timeout)
            return self.position()

    def await_motion(self, *, cancel: Cancel = None, timeout: float | None = None) -> None:
        """``A``: wait until both axes stop; interruptible, bounded by ``move_timeout``."""
        timeout = self.move_timeout if timeout is None else float(timeout)
        user_stop = _stop_fn(cancel)
        with self.lock:
            self._send("A")
            try:
                reply = self._read_reply("A", timeout, stop=lambda: user_stop() or self._halt.is_set())
            except ReplyTimeout as exc:
                answered, where = self._halt_after_await()
                if not answered:
                    raise ReplyTimeout(
                        f"no reply to A within {timeout:g}s and none to H after it: the unit stopped "
                        f"answering mid-move; check cable, power and baud rate ({self.port} at "
                        f"{self.baudrate} baud)"
                    ) from exc
                raise DeviceError(
                    DEVICE,
                    f"move did not finish within {timeout:g}s (drivers.ptu.move_timeout); the unit stopped "
                    f"at {where} short of its target and was halted; the axes may be stalled, blocked or "
                    "overloaded; check the load and power, then reset the PTU",
                ) from exc
            if reply is None:
                if self._halt.is_set():  # halt(): its caller waits for the axes to stand
                    _, where = self._halt_after_await()
                    raise MoveInterrupted(f"move interrupted by halt at {where}", self._last_position())
                where = self._halt_during_await(timeout)
                raise MoveInterrupted(f"move interrupted at {where}; the axes decelerate to a stop from there",
                                      where)
            if not reply.ok:
                raise DeviceError(DEVICE, f"the PTU refused A: {reply.text}")
            self._set_state(moving=False)

    def _halt_during_await(self, timeout: float) -> tuple[float, float]:
        """Send H while an A is outstanding, read the first of the two bare replies (the H's, or
        the A's if the axes had just stopped), then where the axes are: the unit answers PP/TP
        while it decelerates, and the other bare reply, whenever it comes, is told apart from
        their numbers. If it has not come by then it is left to :meth:`_finish_halt`."""
        self._send("H", flush=False)
        self._read_reply("H", self.timeout)
        self._await_until = time.monotonic() + timeout
        counts: list[int] = []
        for cmd in ("PP", "TP"):
            self._write(encode_command(cmd))  # not _send: that would wait for the outstanding reply first
            while True:
                reply = self._read_reply(cmd, self.timeout)
                assert reply is not None
                if reply.ok and reply.number() is None and self._await_until is not None:
                    self._await_until = None  # the A's reply: the axes stand
                    self._set_state(moving=False)
                    continue
                break
            value = reply.number() if reply.ok else None
            if value is None:
                raise DeviceError(DEVICE, f"the PTU answered {cmd} after a halt with {reply.text!r}")
            counts.append(int(value))
        pan_deg, tilt_deg = self.to_degrees("pan", counts[0]), self.to_degrees("tilt", counts[1])
        self._set_state(pan_pos=counts[0], tilt_pos=counts[1], pan_deg=pan_deg, tilt_deg=tilt_deg)
        return pan_deg, tilt_deg

    def _finish_halt(self) -> None:
        """Read the reply a halted move still owes (the A's once the axes stand, or the H's),
        then where the axes stopped, so the next command starts from a known position."""
        until, self._await_until = self._await_until, None
        assert until is not None
        self._read_reply("A", max(until - time.monotonic(), self.timeout))
        self._set_state(moving=False)
        self.position()

    def _halt_after_await(self) -> tuple[bool, str]:
        """Send H while an A is outstanding and collect both replies (the H's and the A's, in
        whichever order the unit sends them); whether the unit answered, and where it is."""
        self._send("H", flush=False)
        answered = False
        for _ in range(2):
            try:
                self._read_reply("H", self.timeout)
                answered = True
            except ReplyTimeout:
                break
        self._set_state(moving=False)
        if not answered:
            return False, "an unknown position"
        try:
            pan, tilt = self.position()
            return True, f"pan {pan:.2f} deg, tilt {tilt:.2f} deg"
        except DeviceError:
            return True, "an unknown position (no reply to PP/TP)"

    def _last_position(self) -> tuple[float, float] | None:
        with self._state_lock:
            pan, tilt = self._state["pan_deg"], self._state["tilt_deg"]
        return None if pan is None or tilt is None else (pan, tilt)

    def interrupt(self) -> None:
        """Ask a move that is awaiting (in another thread) to halt; ``halt()`` does this first."""
        self._halt.set()

    def halt(self) -> None:
        """Stop both axes now, also from another thread while a move is awaiting."""
        self._halt.set()
        try:
            with self.lock:
                self.command("H")
                self._set_state(moving=False)
        finally:
            self._halt.clear()

    def reset(self, timeout: float | None = None, *, cancel: Cancel = None) -> tuple[float, float]:
        """``R``: the unit runs both axes into their limits and back home; wait for the end.

        The D46 measures its axis bounds during a reset, so they are read again afterwards. A
        ``cancel`` stops the wait, not the unit (it takes no command until its reset ends): the
        client remembers the outstanding R and its next command waits for it first.
        """
        user_stop = _stop_fn(cancel)
        timeout = self.reset_timeout if timeout is None else float(timeout)
        with self.lock:
            self._set_state(moving=True, target_pan_deg=0.0, target_tilt_deg=0.0)
            self._send("R")
            reply = self._read_reply("R", timeout, stop=lambda: user_stop() or self._halt.is_set())
            if reply is None:
                self._reset_until = time.monotonic() + timeout
                raise MoveInterrupted(
                    f"reset interrupted: the unit finishes it on its own (up to {timeout:g}s, "
                    "drivers.ptu.reset_timeout) and its next command waits for that", self._last_position())
            if not reply.ok:
                raise DeviceError(DEVICE, f"the PTU refused R: {reply.text}")
            return self._after_reset()

    def _finish_reset(self) -> None:
        """Wait out an interrupted R (its reply is the next one on the line), then re-read what a
        reset changes."""
        until, self._reset_until = self._reset_until, None
        assert until is not None
        self._read_reply("R", max(until - time.monotonic(), self.timeout))
        self._after_reset()

    def _after_reset(self) -> tuple[float, float]:
        self._set_state(moving=False)
        for axis, letter in (("pan", "P"), ("tilt", "T")):
            self.bounds[axis] = (int(self.query_number(f"{letter}N")), int(self.query_number(f"{letter}X")))
        return self.position()

    # -- speeds, accelerations, health -----------------------------------------------------------
    def set_speed(self, pan: float | None, tilt: float | None = None) -> None:
        """Speeds in positions/s; the unit's bounds (PL/PU) are its own to enforce."""
        with self.lock:
            for letter, value in (("P", pan), ("T", tilt)):
                if value is not None:
                    self.command(f"{letter}S{int(round(value))}")

    def set_acceleration(self, pan: float | None, tilt: float | None = None) -> None:
        """Accelerations in positions/s^2."""
        with self.lock:
            for letter, value in (("P", pan), ("T", tilt)):
                if value is not None:
                    self.command(f"{letter}A{int(round(value))}")

    def get_speed(self) -> tuple[int, int]:
        with self.lock:
            return int(self.query_number("PS")), int(self.query_number("TS"))

    def get_acceleration(self) -> tuple[int, int]:
        with self.lock:
            return int(self.query_number("PA")), int(self.query_number("TA"))

    def motion(self) -> dict[str, dict[str, float]]:
        """Per axis what its moves' durations follow from, in degrees: speed, acceleration and
        base (start-up) speed as the unit holds them now."""
        with self.lock:
            return {axis: {key: self.to_degrees(axis, self.query_number(f"{axis[0].upper()}{letter}"))
                           for key, letter in (("speed", "S"), ("acceleration", "A"), ("base", "B"))}
                    for axis in ("pan", "tilt")}

    def power_status(self) -> dict[str, object]:
        reply = self.command("O", number=True)
        try:
            return parse_power(reply.text)
        except ValueError as exc:
            raise DeviceError(DEVICE, f"unreadable reply to O: {reply.line!r}") from exc

    def firmware(self) -> str:
        return self.command("V").text

    # -- status --------------------------------------------------------------------------------
    def _set_state(self, **values: Any) -> None:
        with self._state_lock:
            self._state.update(values)

    def snapshot(self) -> dict[str, Any]:
        """Never waits for the serial line: the last values the unit reported."""
        with self._state_lock:
            state = dict(self._state)
        state["resolution_arcsec"] = dict(self.resolution)
        state["limits"] = self.limits() if self.resolution and self.bounds else None
        return state
