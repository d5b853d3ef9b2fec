"""Fuzzing the wire protocol: request lines generated from the command table and mutated, a
reference model of how many replies a byte stream must get, which lines the bulk fuzz must not
send, and a client that sends plans over many connections and counts what comes back.

The reliability suites (tests/reliability, docs/RELIABILITY.md) use it; their long versions run
only with ``RVS_LONG=1`` (the marks in ``tests/support/marks.py``).
"""

from __future__ import annotations

import asyncio
import json
import random
import re
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from rvs_server import commands as _commands  # noqa: F401 - fills the command table
from rvs_server.main import build_config
from rvs_server.protocol import MAX_LINE, WILL_TIMING_MARK, ProtocolError, parse_reply, parse_request
from rvs_server.table import COMMANDS, Command, bind_options, check_positional, lookup
from support.server import FINAL

TAIL_KEEP = 40


# ------------------------------------------------------------------------------------------ model


IAC_SEQUENCE = re.compile(rb"\xff(?:[\xfb-\xfe][\x00-\xff]?|[\x00-\xfa\xff])?")


def strip_iac(data: bytes) -> tuple[bytes, bool]:
    """Remove telnet IAC sequences from a fresh stream: IAC + command, plus an option byte after
    WILL/WONT/DO/DONT (PROTOCOL.md, Transport). The flag says whether a sequence was left open
    at the end (it would swallow the bytes that come next)."""
    if b"\xff" not in data:
        return data, False
    last = None
    for match in IAC_SEQUENCE.finditer(data):
        last = match
    seq = last.group() if last is not None else b""
    open_ = last is not None and last.end() == len(data) and (len(seq) == 1 or (len(seq) == 2 and 0xFB <= seq[1] <= 0xFE))
    return IAC_SEQUENCE.sub(b"", data), open_


def close_iac(piece: bytes) -> bytes:
    """Make a line piece self-contained: an IAC left open at its end would eat the LF after it
    (and join it to the next line); one more byte closes it."""
    _, open_ = strip_iac(piece)
    return piece + b"A" if open_ else piece


def telnet_text(data: bytes) -> bytes:
    """A stream as the server reads it: IAC sequences out, telnet's CR NUL as a bare CR."""
    text, _ = strip_iac(data)
    return text.replace(b"\r\x00", b"\r")


def telnet_commands(piece: bytes) -> tuple[int, int]:
    """(interrupts, timing marks) in a self-contained piece: telnet's Ctrl-C sends IAC IP (the
    server breaks the job this connection started, if one runs) and IAC DO TIMING-MARK (the
    server answers IAC WILL TIMING-MARK, in order with the replies; PROTOCOL.md, Transport)."""
    if b"\xff" not in piece:
        return 0, 0
    seqs = [m.group() for m in IAC_SEQUENCE.finditer(piece)]
    return seqs.count(b"\xff\xf4"), seqs.count(b"\xff\xfd\x06")


def logical_line(piece: bytes) -> bytes:
    """What the server parses from one self-contained piece sent as ``piece + LF``."""
    text = telnet_text(piece)
    return text[:-1] if text.endswith(b"\r") else text


def expects_reply(piece: bytes, max_line: int = MAX_LINE, logical: bytes | None = None) -> bool:
    """PROTOCOL.md: every request that is not blank or a comment gets exactly one final line; an
    over-long line is one E_TOOLONG; bytes that are not UTF-8 are one E_SYNTAX, unless they are
    a comment (docs/PROTOCOL.md: blank and comment lines get no reply whatever their bytes)."""
    line = logical_line(piece) if logical is None else logical
    if len(line) > max_line:
        return True
    stripped = line.strip(b" \t\r")  # telnet clients may send CR CR LF
    return bool(stripped) and not stripped.startswith(b"#")


def reply_facts(raw: str) -> tuple[str, str, str | None, str | None, str | None]:
    """(module, status, tag, job, code) of one reply line, text or JSON; ValueError if neither."""
    if raw.startswith("{"):
        obj = json.loads(raw)
        if not isinstance(obj, dict) or "module" not in obj or "status" not in obj:
            raise ValueError(f"not a JSON reply: {raw[:80]!r}")
        job = obj.get("job")
        return str(obj["module"]), obj["status"], obj.get("tag"), None if job is None else str(job), obj.get("code")
    try:
        r = parse_reply(raw)
    except ProtocolError as exc:
        raise ValueError(str(exc)) from None
    return r.module, r.status, r.tag, r.fields.get("job"), r.fields.get("code")


# ------------------------------------------------------------------------------------------ generators

TAG_CHARS = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.:-"
STEM_CHARS = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_.-"
WEIRD_TEXT = ["\u2013", "\u2014", "\u2028", "\u2029", "\u0085", "\ufeff", "\u202e", "\u0301", "\u00e9", "\u2024",
              "\u2215", "\uff0f", "\U0001f680", "\x00", "\x1b[31m", "\t", "\r", "\\", '"', "=", "#", "@", "'", "~",
              "$(id)", "%s%n", "..", "/", "\u0661\u0662", "\u00a0", " "]
BARE_SAFE = re.compile(r"[A-Za-z0-9_.,:+/\-]+")
DASHES = ("-", "-", "-", "--", "\u2013")
POSITIONAL_WORDS = {
    "help": lambda rng: rng.choice(list(COMMANDS) + ["EGP-RVS-GRAB-TOF", "nosuch", "HELP"]),
    "events": lambda rng: rng.choice(["on", "off", "OFF", "maybe"]),
    "format": lambda rng: rng.choice(["text", "json", "JSON", "xml"]),
    "sim": lambda rng: rng.choice(["truth", "move-rover", "scene", "fault", "dance"]),
}


@dataclass
class GenRequest:
    """A generated request line and what parsing it must give back."""

    line: str
    command: str
    tag: str | None
    options: list[tuple[str, str | bool]] = field(default_factory=list)
    positional: list[str] = field(default_factory=list)


def quote(value: str) -> str:
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def bare_ok(value: str) -> bool:
    """A value that may go unquoted: safe characters and not mistakable for an option."""
    if not BARE_SAFE.fullmatch(value):
        return False
    stripped = value.lstrip("-")
    return not (value.startswith("-") and stripped[:1].isalpha())


class LineGen:
    """Request lines from the command table with random options and values, and mutations of
    them. Works on any ``random.Random``-like source: a seeded one for the bulk server fuzz,
    hypothesis's ``st.randoms()`` for the property tests (so their failures shrink)."""

    def __init__(self, rng: Any, commands: Iterable[str] | None = None) -> None:
        self.rng = rng
        self.names = sorted(commands if commands is not None else COMMANDS)

    # -- pieces
    def tag(self) -> str:
        n = self.rng.randint(1, 32)
        return "".join(self.rng.choice(TAG_CHARS) for _ in range(n))

    def stem(self) -> str:
        n = self.rng.randint(1, 64)
        first = self.rng.choice(STEM_CHARS.replace(".", ""))
        s = first + "".join(self.rng.choice(STEM_CHARS) for _ in range(n - 1))
        return s.replace("..", "._")

    def text(self, max_len: int = 24) -> str:
        parts = []
        for _ in range(self.rng.randint(0, 6)):
            if self.rng.random() < 0.4:
                parts.append(self.rng.choice(WEIRD_TEXT))
            else:
                parts.append("".join(self.rng.choice(STEM_CHARS + " ") for _ in range(self.rng.randint(1, 8))))
        return "".join(parts)[:max_len]

    def number(self, lo: float | None, hi: float | None, integer: bool) -> str:
        rng = self.rng
        lo_v = -1e6 if lo is None else lo
        hi_v = 1e6 if hi is None else hi
        pick = rng.random()
        if pick < 0.55:
            v = rng.uniform(lo_v, hi_v)
        elif pick < 0.7:
            v = rng.choice([lo_v, hi_v])
        elif pick < 0.85:
            v = rng.choice([lo_v - 1, hi_v + 1, lo_v - 1e9, hi_v * 10 + 1])
        else:
            return rng.choice(["abc", "1e309", "-1e309", "nan", "inf", "-0", "1_0", "0x10", "1,5", "", "--",
                               "\u0661\u0662", "1e-400", "9" * 400, ".5", "5.", "+3", "1e3", " 7"])
        if integer:
            return str(int(round(v)))
        return rng.choice([f"{v:.3f}", f"{v:g}", repr(v), f"{v:.0f}"])

    def value(self, spec: Any) -> str | bool:
        rng = self.rng
        if spec.kind == "bool":
            return rng.choice([True, "true", "false", "yes", "0", "1", "maybe", "TRUE"])
        if spec.kind == "floats":
            lo, hi = spec.length or (1, 6)
            n = rng.choice([lo, hi, lo, rng.randint(0, hi + 2)])
            return ",".join(self.number(spec.min, spec.max, False) for _ in range(n))
        if spec.kind in ("float", "int"):
            return self.number(spec.min, spec.max, spec.kind == "int")
        if spec.choices:
            pick = rng.random()
            if pick < 0.75:
                c = rng.choice(spec.choices)
                return c.upper() if rng.random() < 0.2 else c
            return self.text(12) or "x"
        if spec.stem:
            return self.stem() if rng.random() < 0.7 else self.text(70)
        return self.text()

    def option_name(self, name: str) -> str:
        rng = self.rng
        flag = name.replace("_", rng.choice(["-", "-", "_"]))
        if rng.random() < 0.2:
            flag = "".join(c.upper() if rng.random() < 0.5 else c for c in flag)
        return flag

    def render_value(self, value: str) -> str:
        if bare_ok(value) and self.rng.random() < 0.8:
            return value
        return quote(value)

    # -- whole requests
    def request(self, tag: str | None = None, command: str | None = None, use_tag: float = 0.5) -> GenRequest:
        """A well-formed request line (it parses) with options drawn from the command's config
        class: some valid, some out of range, unknown, mistyped or repeated (E_ARG)."""
        rng = self.rng
        name = command or rng.choice(self.names)
        cmd = COMMANDS.get(name)
        if tag is None and rng.random() < use_tag:
            tag = self.tag()
        shown = name
        r = rng.random()
        if r < 0.1 and cmd is not None:
            shown = cmd.module
        elif r < 0.2:
            shown = name.upper()
        parts = [shown]
        if tag is not None:
            parts.insert(0, "@" + tag)
        positional: list[str] = []
        if name in POSITIONAL_WORDS and rng.random() < 0.7:
            word = POSITIONAL_WORDS[name](rng)
            positional.append(word)
            parts.append(word)
        options: list[tuple[str, str | bool]] = []
        specs = [s for s in cmd.config.keys().values() if s.option] if cmd and cmd.config and not cmd.raw else []
        if name == "config":
            specs = []
            if rng.random() < 0.8:
                module = rng.choice(["sleep", "grab_tof", "server", "drivers", "EGP-RVS-SLEEP", "nosuch"])
                options.append(("module", module))
        chosen = [s for s in specs if rng.random() < 0.5]
        rng.shuffle(chosen)
        for spec in chosen:
            options.append((spec.name, self.value(spec)))
        if rng.random() < 0.1:  # an unknown option, or one given twice
            extra = rng.choice(specs).name if specs and rng.random() < 0.5 else rng.choice(["bogus", "x1", "verbose"])
            options.append((extra, self.value(specs[0]) if specs else "1"))
        for i, (oname, value) in enumerate(options):
            flag = rng.choice(DASHES) + self.option_name(oname)
            is_last = i == len(options) - 1
            if value is True:
                if is_last or rng.random() < 0.5:
                    parts.append(flag)
                else:
                    parts.append(flag + "=true")
                    options[i] = (oname, "true")
                continue
            rendered = self.render_value(value)
            parts.append(flag + "=" + rendered if rng.random() < 0.25 else flag + " " + rendered)
        sep = rng.choice([" ", " ", " ", "  ", "\t"])
        line = sep.join(parts)
        if rng.random() < 0.1:
            line = rng.choice([" ", "\t", "  "]) + line
        return GenRequest(line, shown, tag, [(n.lower(), v) for n, v in options], positional)

    def junk(self) -> str:
        """Lines that are not requests at all, or barely."""
        rng = self.rng
        return rng.choice([
            lambda: "",
            lambda: "   \t ",
            lambda: "# " + self.text(),
            lambda: "  #" + self.text(),
            lambda: self.text(40),
            lambda: "@" + self.text(10),
            lambda: "@" + self.tag() + " " + self.text(12),
            lambda: '"' + self.text(10),
            lambda: "-" + self.text(10),
            lambda: rng.choice(self.names) + ' -x "unterminated',
            lambda: rng.choice(self.names) + ' -x "bad \\q escape"',
            lambda: "frobnicate -x 1",
            lambda: "EGP-RVS-" + self.text(8),
            lambda: "\u2013output x",
        ])()

    # -- mutations of real lines
    def mutate(self, data: bytes, ops: int | None = None) -> bytes:
        rng = self.rng
        buf = bytearray(data)
        for _ in range(ops or rng.randint(1, 3)):
            pos = rng.randint(0, len(buf))
            op = rng.randint(0, 13)
            if op == 0 and buf:  # bit flip
                i = rng.randint(0, len(buf) - 1)
                buf[i] ^= 1 << rng.randint(0, 7)
            elif op == 1:  # telnet IAC sequences, some cut short
                buf[pos:pos] = rng.choice([b"\xff\xfb\x01", b"\xff\xfd\x03", b"\xff\xf1", b"\xff\xff", b"\xff",
                                           b"\xff\xfe", b"\xff\xf4\xff\xfd\x06"])
            elif op == 2:
                buf[pos:pos] = b"\x00" * rng.randint(1, 3)
            elif op == 3:
                buf[pos:pos] = rng.choice([b"\r", b"\r\r", b"\r\n"])
            elif op == 4:  # huge token: near, at and over the line limit
                n = rng.choice([64, 1000, MAX_LINE - len(buf), MAX_LINE + 1, 5000, 70_000])
                buf[pos:pos] = b"x" * max(n, 1)
            elif op == 5:  # truncate (unbalanced quotes, dangling escapes)
                del buf[pos:]
            elif op == 6:
                buf[pos:pos] = rng.choice([b'"', b"\\", b'\\"', b"=", b" -", b"\xe2\x80\x93", b"@", b"#"])
            elif op == 7:
                buf[pos:pos] = rng.choice(WEIRD_TEXT).encode("utf-8", "surrogatepass")
            elif op == 8:  # bytes that are not UTF-8
                buf[pos:pos] = rng.choice([b"\xc3\x28", b"\xed\xa0\x80", b"\x80", b"\xf8\x88\x80\x80\x80", b"\xfe"])
            elif op == 9 and buf:
                a = rng.randint(0, len(buf) - 1)
                b = rng.randint(a, min(len(buf), a + 40))
                buf[pos:pos] = buf[a:b]
            elif op == 10 and buf:
                a = rng.randint(0, len(buf) - 1)
                del buf[a : rng.randint(a, min(len(buf), a + 10))]
            elif op == 11 and buf:
                buf[rng.randint(0, len(buf) - 1)] = rng.randint(0, 255)
            elif op == 12:
                buf[pos:pos] = rng.choice([b" ", b"\t", b"  ", b"\x0b", b"\x0c"])
            else:
                buf[pos:pos] = b"\n"  # one line becomes two
        return bytes(buf)


# ------------------------------------------------------------------------------------------ safety


_STORE = None


def _default_config(cmd: Command) -> Any:
    global _STORE
    if _STORE is None:
        _STORE = build_config(None, [])
    return _STORE.values.get(cmd.config.module) if cmd.config is not None else None


CHEAP_JOBS = {"sleep", "move-ptu", "grab-tof", "grab-stereo", "continue", "reset", "reinit", "recover"}
SAFE_IMMEDIATE = {"help", "status", "version", "events", "format", "config", "pose", "auth", "check-move", "standby",
                  "break", "sim", "hazard-stop", "track3d-stop"}
SAFE_STEMS = {"fz0", "fz1", "fz2"}


def hazard(logical: bytes) -> str | None:
    """Why the bulk fuzz must not send a line (None: it may). Requests that would end the server
    (quit), change its configuration, fill the disk, start monitors or run long jobs are not what
    fuzzing the parser and dispatcher is about (they are tested on purpose elsewhere): only the
    commands listed here run; every other one is sent in forms that are refused."""
    try:
        text = logical.decode("utf-8")
        req = parse_request(text)
    except (UnicodeDecodeError, ProtocolError):
        return None
    if req is None:
        return None
    cmd = lookup(req.command)
    if cmd is None:
        return None
    name = cmd.name
    if name == "config" and any(k == "set" for k, _ in req.options):
        return "config -set"
    if name == "sim" and not (req.positional and req.positional[0].lower() in ("truth", "move-rover")):
        return "sim scene/fault"
    if name not in SAFE_IMMEDIATE and name not in CHEAP_JOBS:
        # quit, logbook (copies the log: disk), monitors (hazard-start, track3d-start) and any
        # command that lands later: sent only in forms that are refused (E_ARG)
        try:
            check_positional(cmd, req)
            bind_options(cmd, _default_config(cmd), req)
        except Exception:  # noqa: BLE001 - refused (E_ARG), or a server bug the fuzz will report
            return None
        return f"{name} would run"
    if not cmd.job:
        return None
    try:
        check_positional(cmd, req)
        cfg = bind_options(cmd, _default_config(cmd), req)
    except Exception:  # noqa: BLE001 - refused (E_ARG), or a server bug the fuzz will report
        return None
    if name == "sleep" and cfg.seconds > 0.2:
        return "long sleep"
    if name == "grab-tof" and (cfg.integrate > 4 or cfg.output not in SAFE_STEMS):
        return "grab-tof that adds files"
    if name == "grab-stereo" and (cfg.resolution != "low" or cfg.output not in SAFE_STEMS):
        return "grab-stereo that adds files or renders long"
    return None


# ------------------------------------------------------------------------------------------ plans


@dataclass
class Plan:
    """What one fuzzing connection sends: self-contained pieces, each sent as ``piece + LF``."""

    pieces: list[bytes] = field(default_factory=list)
    expected: int = 0
    tags: set[str] = field(default_factory=set)  # unique tags of unmutated requests: one final each
    kinds: dict[str, int] = field(default_factory=dict)
    seen_tags: dict[str, int] = field(default_factory=dict)  # every line that starts with @word
    interrupts: int = 0  # telnet IAC IP: each may add one untagged break reply (if a job of ours runs)
    marks: int = 0  # telnet IAC DO TIMING-MARK: each is answered by exactly one IAC WILL TIMING-MARK

    def add(self, raw: bytes, tag: str | None, kind: str) -> None:
        for part in raw.split(b"\n"):
            piece = close_iac(part)
            self.pieces.append(piece)
            interrupts, marks = telnet_commands(piece)
            self.interrupts += interrupts
            self.marks += marks
            logical = logical_line(piece)
            if expects_reply(piece, logical=logical):
                self.expected += 1
            m = re.match(rb"[ \t]*@(\S+)", logical[:100])
            if m:
                word = m.group(1).decode("utf-8", "replace")
                self.seen_tags[word] = self.seen_tags.get(word, 0) + 1
        if tag is not None:
            self.tags.add(tag)
        self.kinds[kind] = self.kinds.get(kind, 0) + 1

    @property
    def unique_tags(self) -> set[str]:
        """Tags no other line of the plan carries (a mutation may turn @mr1n5 into @r1n5)."""
        return {t for t in self.tags if self.seen_tags.get(t, 0) == 1}


JOB_LINES = (
    "sleep -seconds 0.05", "sleep -seconds 0", "move-ptu -pan {a} -tilt {b}", "grab-tof -output fz0 -type z",
    "grab-tof -output fz1 -integrate 2", "grab-stereo -output fz2 -resolution low", "break", "continue",
    "reinit -device tof", "reset", "standby", "events off", "events on", "format json", "format text",
    "status", "recover",
)


def make_plan(gen: LineGen, n: int, prefix: str, mutate_share: float = 0.45, junk_share: float = 0.1,
              job_share: float = 0.04) -> Plan:
    """``n`` lines for one connection: valid-grammar requests with unique tags, junk, mutations
    of real request lines, and a few real jobs, breaks and mode and format switches; nothing that
    :func:`hazard` refuses."""
    plan = Plan()
    i = 0
    while i < n:
        rng = gen.rng
        r = rng.random()
        tag = None
        if r < job_share:
            tag = f"{prefix}n{i}"
            line = rng.choice(JOB_LINES).format(a=rng.randint(-150, 150), b=rng.randint(-45, 30))
            raw, kind = f"@{tag} {line}".encode(), "job"
        elif r < job_share + junk_share:
            raw, kind = gen.junk().encode("utf-8", "surrogatepass"), "junk"
        elif r < job_share + junk_share + mutate_share:
            req = gen.request(tag=f"m{prefix}n{i}" if rng.random() < 0.5 else None)
            raw, kind = gen.mutate(req.line.encode("utf-8", "surrogatepass")), "mutated"
        else:
            tag = f"{prefix}n{i}"
            raw, kind = gen.request(tag=tag).line.encode("utf-8", "surrogatepass"), "request"
        parts = [close_iac(p) for p in raw.split(b"\n")]
        if any(hazard(logical_line(p)) for p in parts):
            continue
        plan.add(raw, tag, kind)
        i += 1
    return plan


# ------------------------------------------------------------------------------------------ driving


@dataclass
class ConnResult:
    """What one connection got back. ``finals`` counts the final lines that answer the plan's
    lines: a telnet interrupt (IAC IP) that found a job of this connection running is answered by
    an untagged ``break`` reply of its own; whether the job still ran then is up to timing, so
    those replies (at most one per interrupt, and only untagged EGP-RVS-BREAK ones) are counted
    apart in ``interrupt_breaks``."""

    expected: int
    finals: int = 0
    interrupts: int = 0  # IAC IP sent
    untagged_breaks: int = 0  # untagged EGP-RVS-BREAK final lines read
    interrupt_breaks: int = 0
    marks_expected: int = 0
    marks: int = 0  # IAC WILL TIMING-MARK read
    tag_finals: dict[str, int] = field(default_factory=dict)
    missing_tags: list[str] = field(default_factory=list)
    internal: list[str] = field(default_factory=list)
    malformed: list[str] = field(default_factory=list)
    lines: int = 0
    error: str | None = None
    seconds: float = 0.0
    tail: list[str] = field(default_factory=list)  # the last lines read, for failure messages


async def drive_connection(port: int, plan: Plan, sync_tag: str, rng: random.Random,
                           timeout: float = 120.0, host: str = "127.0.0.1") -> ConnResult:
    """Send a plan (in random chunk sizes, as TCP may cut it) while reading every reply; then a
    tagged ``version`` whose final line marks the end of the immediate replies, then wait for
    the final lines of the jobs still running."""
    res = ConnResult(plan.expected, interrupts=plan.interrupts, marks_expected=plan.marks)
    t0 = time.monotonic()
    reader, writer = await asyncio.open_connection(host, port, limit=1 << 22)
    hello = await asyncio.wait_for(reader.readline(), 30)
    if b"kind=hello" not in hello:
        res.error = f"no greeting: {hello[:100]!r}"
        writer.close()
        return res
    stream = b"".join(p + b"\n" for p in plan.pieces) + f"@{sync_tag} version\n".encode()
    open_jobs: dict[str, tuple[str, str | None]] = {}  # job id -> (module, tag) of its ACK
    synced = asyncio.Event()

    async def write() -> None:
        i = 0
        while i < len(stream):
            n = rng.choice([1, 7, 64, 512, 4096, 65536])
            writer.write(stream[i : i + n])
            i += n
            if rng.random() < 0.3:
                await writer.drain()
        await writer.drain()

    async def read() -> None:
        while True:
            raw = await reader.readline()
            if not raw:
                raise ConnectionError("server closed the connection")
            res.lines += 1
            while raw.startswith(WILL_TIMING_MARK):  # written between two reply lines
                res.marks += 1
                raw = raw[len(WILL_TIMING_MARK):]
            text = raw.decode("utf-8", "replace").rstrip("\r\n")
            res.tail.append(text[:160])
            if len(res.tail) > TAIL_KEEP:
                del res.tail[:20]
            try:
                module, status, tag, job, code = reply_facts(text)
            except ValueError:
                res.malformed.append(text[:200])
                continue
            if code == "E_INTERNAL":
                res.internal.append(text[:300])
            if status == "ACK" and job is not None:
                open_jobs[job] = (module, tag)
            if status not in FINAL:
                continue
            if tag == sync_tag:
                synced.set()
            else:
                res.finals += 1
                if tag is None and module == "EGP-RVS-BREAK":
                    res.untagged_breaks += 1
                if tag is not None and tag in plan.tags:
                    res.tag_finals[tag] = res.tag_finals.get(tag, 0) + 1
            # A job's own final line: its id, module and tag, and not E_BUSY (which names the
            # running job, as status does with job=<running id>).
            if job in open_jobs and open_jobs[job] == (module, tag) and code != "E_BUSY":
                del open_jobs[job]
            if synced.is_set() and not open_jobs:
                return

    try:
        await asyncio.wait_for(asyncio.gather(write(), read()), timeout)
    except (TimeoutError, ConnectionError, OSError) as exc:
        res.error = f"{type(exc).__name__}: {exc} (open jobs {sorted(open_jobs)}, synced {synced.is_set()})"
    finally:
        writer.close()
        try:
            await writer.wait_closed()
        except (ConnectionError, OSError):
            pass
    res.missing_tags = sorted(t for t in plan.unique_tags if res.tag_finals.get(t, 0) != 1)
    extra = res.finals - res.expected
    if 0 < extra <= min(res.interrupts, res.untagged_breaks):
        res.interrupt_breaks = extra
        res.finals -= extra
    res.seconds = time.monotonic() - t0
    return res


def drive(port: int, plans: Sequence[Plan], seed: int, timeout: float = 300.0) -> list[ConnResult]:
    """All plans at once, one connection each."""

    async def main() -> list[ConnResult]:
        rngs = [random.Random(seed * 1000 + i) for i in range(len(plans))]
        return list(await asyncio.gather(*(
            drive_connection(port, plan, f"sync-{i}", rngs[i], timeout) for i, plan in enumerate(plans)
        )))

    return asyncio.run(main())


def summarize(results: Sequence[ConnResult]) -> dict[str, Any]:
    return {
        "expected": sum(r.expected for r in results),
        "finals": sum(r.finals for r in results),
        "lines_read": sum(r.lines for r in results),
        "errors": [r.error for r in results if r.error],
        "interrupt_breaks": sum(r.interrupt_breaks for r in results),
        "miscounted": [(i, r.expected, r.finals, r.marks_expected, r.marks) for i, r in enumerate(results)
                       if r.finals != r.expected or r.marks != r.marks_expected],
        "missing_tags": [t for r in results for t in r.missing_tags][:20],
        "internal": [x for r in results for x in r.internal][:5],
        "malformed": [x for r in results for x in r.malformed][:5],
    }
