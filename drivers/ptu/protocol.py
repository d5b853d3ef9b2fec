"""The PTU-D46 ASCII command set: unit conversion and a reply parser that survives a noisy line.

The D46 answers every command with one line starting with ``*`` (done, maybe followed by a
query result) or ``!`` (error, followed by the device's message). Between those lines the host
may also see its own command echoed back (echo mode), the verbose wording of a result ("* Current
Pan position is 583") instead of the terse one ("* 583"), asynchronous ``!P``/``!T`` limit hits
glued to other output ("!T!T!P!P*" after a reset), CR, LF or CRLF line ends, and - at a wrong
baud rate - bytes that are not ASCII at all. :class:`ReplyParser` turns that byte stream into
:class:`Reply` objects and counts what it had to throw away, so a timeout can say whether the
line was dead or garbled.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

ARCSEC_PER_DEG = 3600.0
# The factory resolution of a standard PTU-D46 (PR/TR reply) and its factory axis bounds
# (PN/PX/TN/TX replies after a reset), used by the emulator; the client always queries them.
D46_RESOLUTION_ARCSEC = 185.1428
D46_LIMITS = {"pan": (-3090, 3090), "tilt": (-907, 604)}
# Speed bounds (PL/PU) and the power-up speed and acceleration of the emulator; the base
# (start-up) speed is the D46's default (manual v2.14, 4.4.5: "Defaults to 1000 positions/sec").
D46_SPEED_BOUNDS = (31, 2902)
D46_DEFAULT_SPEED = 1000
D46_DEFAULT_ACCEL = 2000
D46_DEFAULT_BASE = 1000
D46_MAX_ACCEL = 30000

# A command ends with a delimiter; the D46 takes a space or a CR. A space keeps an echoed
# command and its reply on one line, which is how the manual prints them ("PP * 22").
DELIMITER = b" "
# Printable ASCII plus the line-end and tab characters a healthy D46 ever sends.
_CLEAN = frozenset(range(0x20, 0x7F)) | {0x09, 0x0A, 0x0D}
_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?")


def deg_to_pos(deg: float, resolution_arcsec: float) -> int:
    """Degrees to the nearest whole position (halves away from zero, symmetric for +-)."""
    x = float(deg) * ARCSEC_PER_DEG / float(resolution_arcsec)
    return int(math.copysign(math.floor(abs(x) + 0.5), x))


def pos_to_deg(pos: float, resolution_arcsec: float) -> float:
    return float(pos) * float(resolution_arcsec) / ARCSEC_PER_DEG


def encode_command(command: str) -> bytes:
    """One command as the D46 wants it: ASCII, upper case, ended by the delimiter."""
    text = command.strip()
    if not text or any(c in text for c in " \r\n\t*!"):
        raise ValueError(f"a PTU command is one word without spaces, '*' or '!': {command!r}")
    try:
        return text.upper().encode("ascii") + DELIMITER
    except UnicodeEncodeError as exc:
        raise ValueError(f"a PTU command is plain ASCII: {command!r}") from exc


def first_number(text: str) -> float | None:
    """The first number in a reply's text: "583", "Current Pan position is 583" and
    "185.1428 seconds arc per Pan position" all carry the value first."""
    m = _NUMBER.search(text)
    return float(m.group()) if m else None


# Refusals that state a bound. Units word them differently: the D46 manual prints "positions/sec",
# a recorded unit "pos/sec"; a speed below PL is "<Axis> speed cannot be less than" in one and
# "Motor speed cannot be less than" (no axis named) in another. Case is not to be relied on.
_POSITION_BOUND = re.compile(r"(maximum|minimum)\s+allowable\s+(pan|tilt)\s+position\s+is\s+([-+]?\d+)", re.I)
_SPEED_BOUND = re.compile(
    r"(?:(pan|tilt|motor)\s+)?speed\s+cannot\s+(exceed|be\s+less\s+than)\s+(\d+)\s*pos(?:itions?)?\s*/\s*s(?:ec)?",
    re.I,
)


@dataclass(frozen=True)
class Bound:
    """A bound a refusal stated: ``kind`` "position" or "speed", ``side`` "min" or "max",
    ``axis`` "pan"/"tilt" or None when the unit did not name it ("Motor speed ...")."""

    kind: str
    side: str
    axis: str | None
    value: int


def parse_bound(text: str) -> Bound | None:
    """The bound stated in a ``!`` reply ("Maximum allowable Pan position is 3091", "Tilt speed
    cannot exceed 4002 pos/sec"), or None for any other refusal. The client updates what it
    believes the unit's bounds are from these, so a unit whose limits differ by a few counts
    from what was read at open (a reset re-measures them) is believed over the earlier figure."""
    m = _POSITION_BOUND.search(text)
    if m:
        side = "max" if m.group(1).lower() == "maximum" else "min"
        return Bound("position", side, m.group(2).lower(), int(m.group(3)))
    m = _SPEED_BOUND.search(text)
    if m:
        who = (m.group(1) or "").lower()
        side = "max" if m.group(2).lower() == "exceed" else "min"
        return Bound("speed", side, who if who in ("pan", "tilt") else None, int(m.group(3)))
    return None


def parse_power(text: str) -> dict[str, object]:
    """The ``O`` reply. The D46 prints "Input 30 VDC @ 86 degF" (verbose) and other firmware
    lists more sensors ("12.1 volts, 30 F, 29 F (tilt), 31 F (pan)"); the first number is the
    supply voltage and the following ones are temperatures in degrees Fahrenheit."""
    numbers = [float(n) for n in _NUMBER.findall(text)]
    if not numbers:
        raise ValueError(f"no numbers in the power reply {text!r}")
    voltage, temps = numbers[0], numbers[1:]
    out: dict[str, object] = {"voltage_v": voltage, "temperatures_f": temps, "raw": text}
    if temps:
        out["temperature_f"] = temps[0]
        out["temperature_c"] = round((temps[0] - 32.0) * 5.0 / 9.0, 2)
    return out


@dataclass(frozen=True)
class Reply:
    """One answer to one command: ``ok`` for ``*``, else an error with the device's text."""

    ok: bool
    text: str
    line: str = ""

    def number(self) -> float | None:
        return first_number(self.text) if self.ok else None


@dataclass
class ReplyParser:
    """Feeds on raw bytes, yields replies; keeps the partial line between reads.

    Lines end at CR or LF (empty lines from CRLF vanish). In each line everything before the
    first ``*`` or ``!`` is echo or junk and is skipped; leading ``!P``/``!T`` tokens are limit
    notifications (counted in ``async_events``); a line with bytes no D46 sends (a wrong baud
    rate) is dropped whole and counted in ``noise_bytes``.
    """

    buffer: bytearray = field(default_factory=bytearray)
    async_events: list[str] = field(default_factory=list)
    noise_bytes: int = 0
    noise_sample: bytearray = field(default_factory=bytearray)
    skipped_lines: list[str] = field(default_factory=list)

    def reset(self) -> None:
        self.buffer.clear()
        self.noise_bytes = 0
        self.noise_sample.clear()
        self.skipped_lines.clear()

    def feed(self, data: bytes) -> list[Reply]:
        self.buffer.extend(data)
        replies: list[Reply] = []
        while True:
            cut = _line_end(self.buffer)
            if cut < 0:
                break
            raw = bytes(self.buffer[:cut])
            del self.buffer[: cut + 1]
            reply = self._parse_line(raw)
            if reply is not None:
                replies.append(reply)
        # Bytes no D46 sends never become part of a line: count them now so that a garbled
        # stream without line ends still shows up in the timeout message.
        if any(b not in _CLEAN for b in self.buffer) and len(self.buffer) > 256:
            self._noise(bytes(self.buffer))
            self.buffer.clear()
        return replies

    def pending_noise(self) -> int:
        """Noise counted so far plus unreadable bytes still waiting for a line end."""
        return self.noise_bytes + sum(1 for b in self.buffer if b not in _CLEAN)

    def _noise(self, raw: bytes) -> None:
        self.noise_bytes += sum(1 for b in raw if b not in _CLEAN)
        if len(self.noise_sample) < 16:
            self.noise_sample.extend(raw[: 16 - len(self.noise_sample)])

    def _parse_line(self, raw: bytes) -> Reply | None:
        if not raw:
            return None
        i = _first_marker(raw)
        # Before the marker is echo or junk, never part of the reply: a stray byte there costs
        # nothing; from the marker on, one byte no D46 sends makes the whole reply suspect.
        head, body = (raw, b"") if i < 0 else (raw[:i], raw[i:])
        if any(b not in _CLEAN for b in head):
            self._noise(head)
        if i < 0:
            if head.strip() and not any(b not in _CLEAN for b in head):
                self.skipped_lines.append(head.decode("ascii"))  # echo of a CR-ended command, a banner
            return None
        if any(b not in _CLEAN for b in body):
            self._noise(body)
            return None
        line = raw.decode("ascii", "replace")
        rest = body.decode("ascii")
        while len(rest) >= 2 and rest[0] == "!" and rest[1] in "PTpt" and not rest[2:3].isalnum():
            self.async_events.append("!" + rest[1].upper())
            rest = rest[2:].lstrip()
            j = _first_marker(rest)
            if j < 0:
                return None
            rest = rest[j:]
        if not rest:
            return None
        return Reply(ok=rest[0] == "*", text=rest[1:].strip(), line=line)


def _line_end(buf: bytearray) -> int:
    cr, lf = buf.find(b"\r"), buf.find(b"\n")
    if cr < 0:
        return lf
    if lf < 0:
        return cr
    return min(cr, lf)


def _first_marker(line: str | bytes) -> int:
    star, bang = ("*", "!") if isinstance(line, str) else (b"*", b"!")
    positions = [p for p in (line.find(star), line.find(bang)) if p >= 0]  # type: ignore[arg-type]
    return min(positions) if positions else -1
