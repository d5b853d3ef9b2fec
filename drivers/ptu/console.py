"""``rvs-ptu``: an interactive console for the PTU, like the thesis's rvs-tof and rvs-cam tools.

Every public driver operation has a prompt command; every error is caught and printed, so a
bench session survives a pulled cable. ``-c "move 30 -10" -c position`` runs lines one-shot
(also ``;``-separated) for scripts and tests; the exit status is 1 if any of them failed, 2 if the
console could not start (a bad option or config). One-shot, stdout holds only the commands'
results; errors go to stderr.
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Any, TextIO

from drivers.console import (
    DEFAULT_CONFIG,
    SETUP_ERRORS,
    DeviceConsole,
    load_section,
    numbers,
    one_line,
    run,
)
from drivers.ptu import BACKENDS, Ptu, create
from rvs_params.cli import ToolParser


def _fmt_pos(pan: float, tilt: float) -> str:
    return f"pan {pan:.3f} deg, tilt {tilt:.3f} deg"


class PtuConsole(DeviceConsole):
    tool = "rvs-ptu"
    intro = "rvs-ptu: PTU-D46 console; 'help' lists the commands, 'quit' leaves."
    prompt = "ptu> "

    def __init__(self, ptu: Ptu, stdout: TextIO | None = None) -> None:
        super().__init__(stdout)
        self.ptu = ptu

    # -- plumbing ------------------------------------------------------------------------------
    def interrupted(self) -> None:
        """Ctrl-C during a move must stop the axes too, not only the wait for them."""
        self.note("interrupted; halting the PTU")
        self._quietly(self.ptu.halt)

    def _quietly(self, fn: Any) -> None:
        try:
            fn()
        except Exception as exc:  # noqa: BLE001
            self.note(f"error: {exc}")

    # -- motion --------------------------------------------------------------------------------
    def do_move(self, arg: str) -> None:
        """move PAN TILT [nowait]: absolute move in degrees; waits unless 'nowait' (Ctrl-C halts)."""
        words = shlex.split(arg)
        wait = not (words and words[-1].lower() == "nowait")
        if not wait:
            words = words[:-1]
        pan, tilt = numbers(" ".join(words), 2, 2, "move PAN TILT [nowait]")
        self.say(_fmt_pos(*self.ptu.move(pan, tilt, wait=wait)))

    def do_pan(self, arg: str) -> None:
        """pan DEG: move the pan axis only."""
        (pan,) = numbers(arg, 1, 1, "pan DEG")
        self.say(_fmt_pos(*self.ptu.move(pan, None)))

    def do_tilt(self, arg: str) -> None:
        """tilt DEG: move the tilt axis only."""
        (tilt,) = numbers(arg, 1, 1, "tilt DEG")
        self.say(_fmt_pos(*self.ptu.move(None, tilt)))

    def do_wait(self, arg: str) -> None:
        """wait: await the end of a 'move ... nowait'."""
        self.say(_fmt_pos(*self.ptu.wait()))

    def do_position(self, arg: str) -> None:
        """position: the current pan and tilt as the unit reports them."""
        self.say(_fmt_pos(*self.ptu.position()))

    do_pos = do_position

    def do_halt(self, arg: str) -> None:
        """halt: stop both axes."""
        self.ptu.halt()
        self.say("halted at " + _fmt_pos(*self.ptu.position()))

    def do_reset(self, arg: str) -> None:
        """reset: the unit's R command (runs the axes into their limits, then home)."""
        self.say("reset done, " + _fmt_pos(*self.ptu.reset()))

    # -- settings and queries ------------------------------------------------------------------
    def do_limits(self, arg: str) -> None:
        """limits: axis bounds in degrees and positions, and the resolution."""
        for axis, lim in self.ptu.limits().items():
            self.say(f"{axis}: {lim['min_deg']:.3f} .. {lim['max_deg']:.3f} deg "
                     f"(positions {lim['min']} .. {lim['max']}, {lim['resolution_arcsec']} arcsec/position)")

    def do_speed(self, arg: str) -> None:
        """speed [PAN [TILT]]: query, or set the speeds in positions/s (one value sets both)."""
        values = numbers(arg, 0, 2, "speed [PAN [TILT]]")
        if values:
            self.ptu.set_speed(values[0], values[-1])
        pan, tilt = self.ptu.speed()
        self.say(f"speed pan {pan} tilt {tilt} positions/s")

    def do_accel(self, arg: str) -> None:
        """accel [PAN [TILT]]: query, or set the accelerations in positions/s^2."""
        values = numbers(arg, 0, 2, "accel [PAN [TILT]]")
        if values:
            self.ptu.set_acceleration(values[0], values[-1])
        pan, tilt = self.ptu.acceleration()
        self.say(f"acceleration pan {pan} tilt {tilt} positions/s^2")

    def do_power(self, arg: str) -> None:
        """power: supply voltage and controller temperature (the O query)."""
        p = self.ptu.power_status()
        temps = ", ".join(f"{t:g} F" for t in p.get("temperatures_f", []))
        self.say(f"supply {p['voltage_v']:g} V, temperatures {temps or 'n/a'}")

    def do_firmware(self, arg: str) -> None:
        """firmware: the unit's version string (V)."""
        self.say(self.ptu.firmware())

    def do_status(self, arg: str) -> None:
        """status: the driver's snapshot (no serial traffic)."""
        for key, value in self.ptu.status().items():
            self.say(f"{key}: {value}")

    def do_check(self, arg: str) -> None:
        """check: talk to the unit to prove it answers."""
        for key, value in self.ptu.check().items():
            self.say(f"{key}: {value}")

    def do_raw(self, arg: str) -> None:
        """raw CMD: send one D46 command as is (e.g. 'raw PP', 'raw FV') and print the reply."""
        if not arg.strip():
            raise ValueError("usage: raw CMD")
        self.say(self.ptu.raw(arg.strip()))

    # -- device lifecycle ----------------------------------------------------------------------
    def do_open(self, arg: str) -> None:
        """open: open the port (and start the emulator for the sim backend)."""
        self.ptu.open()
        self.say(f"open on {self.ptu.status()['port']}")

    def do_reinit(self, arg: str) -> None:
        """reinit: close and reopen the port, redoing the set-up sequence."""
        self.ptu.reinit()
        self.say(f"reinitialised on {self.ptu.status()['port']}")

    def do_close(self, arg: str) -> None:
        """close: close the port (and stop the emulator)."""
        self.ptu.close()
        self.say("closed")

    def do_fault(self, arg: str) -> None:
        """fault KIND: sim only; silent, garbage, stall or none."""
        kind = arg.strip() or None
        self.ptu.inject_fault(kind)
        self.say(f"fault {kind or 'none'} injected (kinds: {', '.join(('None',) + self.ptu.line.faults)})")


def main(argv: list[str] | None = None) -> int:
    parser = ToolParser(prog="rvs-ptu", description="PTU-D46 console (sim or serial backend)")
    parser.add_argument("--backend", choices=BACKENDS.names(), help="default: drivers.yaml ptu.backend")
    parser.add_argument("--port", help="serial port or pyserial URL (serial backend)")
    # the values are typed and checked by drivers.ptu's declarations (below), not by argparse
    parser.add_argument("--baudrate")
    parser.add_argument("--timeout", help="seconds to wait for a reply")
    parser.add_argument("--move-timeout", help="seconds to wait for a move")
    parser.add_argument("--time-scale", help="sim: 0 instant, 1 real time")
    parser.add_argument("--config", type=Path, help=f"drivers YAML (default {DEFAULT_CONFIG})")
    parser.add_argument("-c", "--command", action="append", default=[],
                        help="run this line (';' separates several) and exit; repeatable")
    args = parser.parse_args(argv)

    try:
        config = load_section("ptu", {}, args.config)
        specs = BACKENDS.settings_class().specs()
        for key in ("backend", "port", "baudrate", "timeout", "move_timeout", "time_scale"):
            value = getattr(args, key)
            if value is not None:  # a bad value named as typed here (--time-scale), not as YAML's key
                config[key] = specs[key].parse(value, specs[key].cli_flag)
        ptu = create(config)
    except SETUP_ERRORS as exc:  # a config that cannot be read, a value out of range, an unknown backend
        print(f"rvs-ptu: {one_line(exc)}", file=sys.stderr)
        return 2
    # One-shot too the port opens first: a port that cannot be opened is the run's set-up failing
    # (one line, exit 2), not each command's; what open says is a note (stderr), not a result.
    return run(PtuConsole(ptu), args.command, start="open", close=ptu.close)


if __name__ == "__main__":
    sys.exit(main())
