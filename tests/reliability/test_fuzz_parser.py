"""Fuzzing the pure protocol layer: hypothesis drives the request generator of
tests/support/wire_fuzz.py (valid commands from the table with random options, values, tags, quotes,
escapes, en dashes, numbers and lists) and its byte mutator (bit flips, telnet IAC bytes, NULs,
CRs, huge tokens, truncated quotes, bytes that are not UTF-8).

Properties: a generated request parses back to what was generated; binding its options either
works or is E_ARG; any mutated line costs at most one ProtocolError, never another exception;
the line splitter agrees with an independent model of the byte stream, however TCP cuts it.
"""

from __future__ import annotations

import math
import re

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from support.marks import LONG
from support.wire_fuzz import IAC_SEQUENCE, LineGen, close_iac, expects_reply, logical_line

from rvs_server.main import build_config
from rvs_server.protocol import (
    INTERRUPT,
    MAX_LINE,
    TIMING_MARK,
    LineSplitter,
    ProtocolError,
    Reply,
    Telnet,
    TooLong,
    format_reply,
    format_reply_json,
    is_silent,
    parse_reply,
    parse_request,
)
from rvs_server.table import COMMANDS, bind_options, check_positional, lookup

SCALE = 20 if LONG else 0.5  # the default run half the examples named, RVS_LONG=1 twenty times them
pytestmark = [pytest.mark.long, *([pytest.mark.timeout(1200)] if LONG else [])]  # 20x: minutes, not seconds
STORE = build_config(None, [])
randoms = st.randoms(use_true_random=False)


def examples(n: int) -> settings:
    return settings(max_examples=int(n * SCALE), deadline=None, suppress_health_check=[HealthCheck.too_slow])


def bind(line: str) -> tuple[object, object]:
    """What the dispatcher does with a decoded line short of running it: parse, look the
    command up, check bare words and bind the options over the configured defaults."""
    req = parse_request(line)
    if req is None:
        return None, None
    cmd = lookup(req.command)
    if cmd is None:
        return req, None
    check_positional(cmd, req)
    base = STORE.values.get(cmd.config.module) if cmd.config is not None else None
    return req, bind_options(cmd, base, req)


# ------------------------------------------------------------------------------------ requests


@examples(300)
@given(randoms)
def test_generated_requests_parse_back(rng) -> None:
    gen = LineGen(rng).request()
    req = parse_request(gen.line)
    assert req is not None, gen.line
    assert req.command == gen.command.lower()
    assert req.tag == gen.tag
    assert req.positional == gen.positional
    assert req.options == gen.options, gen.line


@examples(300)
@given(randoms)
def test_options_bind_or_are_e_arg(rng) -> None:
    """Every value the generator can think of for every option of every command: bound and in
    range, or E_ARG with a message; nothing else (no E_INTERNAL)."""
    gen = LineGen(rng).request()
    try:
        req, cfg = bind(gen.line)
    except ProtocolError as exc:
        assert exc.code == "E_ARG", (gen.line, exc.code, exc.message)
        assert exc.message and "\n" not in exc.message
        format_reply(Reply("RVS", "ERROR", {"code": exc.code, "message": exc.message}))
        return
    cmd = lookup(req.command)
    if cfg is None or cmd is None or cmd.raw:
        return
    specs = cfg.keys()
    for name, _ in req.options:
        spec = specs[name]
        value = cfg.value_of(spec)
        if spec.kind in ("float", "int") and (spec.min is not None or spec.max is not None):
            assert math.isfinite(value) and spec.min <= value <= spec.max, (gen.line, name, value)
        if spec.kind == "floats":
            lo, hi = spec.length or (1, 99)
            assert lo <= len(value) <= hi and all(math.isfinite(v) for v in value)
        if spec.choices:
            assert value in spec.choices
        if spec.stem:
            assert "/" not in value and not value.startswith(".") and ".." not in value


@examples(800)
@given(randoms, st.integers(1, 4))
def test_mutated_request_lines_cost_one_protocol_error_at_most(rng, ops) -> None:
    gen = LineGen(rng)
    line = gen.request().line.encode("utf-8", "surrogatepass")
    data = gen.mutate(line, ops)
    for part in data.split(b"\n"):
        piece = close_iac(part)
        logical = logical_line(piece)
        replies = 0
        if len(logical) > MAX_LINE:
            replies = 1  # E_TOOLONG; the content is never looked at
        elif is_silent(logical):
            replies = 0  # blank or a comment, UTF-8 or not
        else:
            try:
                text = logical.decode("utf-8")
            except UnicodeDecodeError:
                replies = 1
            else:
                try:
                    req, _ = bind(text)
                    replies = 0 if req is None else 1
                except ProtocolError as exc:
                    assert exc.code in ("E_SYNTAX", "E_ARG"), (piece, exc.code)
                    assert "\n" not in format_reply(Reply("RVS", "ERROR", {"code": exc.code, "message": exc.message}))
                    replies = 1
        assert replies == int(expects_reply(piece)), piece


@examples(400)
@given(st.lists(randoms.map(lambda r: LineGen(r).junk()), min_size=1, max_size=8))
def test_junk_lines_parse_or_fail_cleanly(lines) -> None:
    for line in lines:
        try:
            bind(line)
        except ProtocolError as exc:
            assert exc.code in ("E_SYNTAX", "E_ARG")


# ------------------------------------------------------------------------------------ bytes to lines


def too_long(line: bytes) -> TooLong:
    """An over-long line as the model sees it: its tag when it starts with ``@tag ``, so the
    E_TOOLONG can carry it."""
    m = re.match(rb"@([A-Za-z0-9_.:\-]{1,32})[ \t\r]", line)
    return TooLong(m.group(1).decode() if m else None)


def model_lines(stream: bytes, max_line: int) -> list[bytes | TooLong | Telnet]:
    """PROTOCOL.md, Transport, written out independently of LineSplitter: IAC sequences out (IAC
    IP and IAC DO TIMING-MARK reported where they stood), CR NUL as CR (telnet), split at LF, one
    CR before the LF dropped, a line over the limit is one TooLong (with its tag).

    Order: a line is reported when its LF is read, an over-long one as soon as it cannot fit
    (one byte kept for a CR), a telnet command when it is read; so a command that stands before
    the byte that decides a line comes before that line."""
    raw = bytearray()
    marks: list[tuple[int, Telnet]] = []  # (text bytes before it, command)
    pos = 0
    for m in IAC_SEQUENCE.finditer(stream):
        raw += stream[pos : m.start()]
        kind = {b"\xff\xf4": INTERRUPT, b"\xff\xfd\x06": TIMING_MARK}.get(m.group())
        if kind is not None:
            marks.append((len(raw), kind))
        pos = m.end()
    raw += stream[pos:]
    text = bytearray()  # CR NUL as CR, keeping where each raw byte went
    at = [0] * (len(raw) + 1)
    i = 0
    while i < len(raw):
        at[i] = len(text)
        text.append(raw[i])
        if raw[i : i + 2] == b"\r\x00":
            at[i + 1] = len(text)
            i += 1
        i += 1
    at[len(raw)] = len(text)
    events: list[tuple[int, int, bytes | TooLong | Telnet]] = [(at[p], 0, kind) for p, kind in marks]
    start = 0
    while True:
        nl = text.find(b"\n", start)
        end = len(text) if nl < 0 else nl
        if end - start > max_line + 1:
            # judged as soon as it cannot fit: its tag is in what had come by then
            events.append((start + max_line + 1, 1, too_long(bytes(text[start:start + max_line + 2]))))
        elif nl >= 0:
            line = bytes(text[start:nl].removesuffix(b"\r"))
            events.append((nl, 1, too_long(line) if len(line) > max_line else line))
        if nl < 0:
            break
        start = nl + 1
    return [item for _, _, item in sorted(events, key=lambda e: (e[0], e[1]))]


stream_parts = st.one_of(
    st.binary(max_size=40),
    st.sampled_from([b"\n", b"\r\n", b"\r", b"\xff", b"\xff\xfb", b"\xff\xfd\x03", b"\xff\xff", b"\xff\n",
                     b"\xff\xf4", b"\xff\xfd\x06",
                     b"\x00", b"\r\x00", b"#", b" ", b"\xe2\x80\x93", b"@t1 ", b"@t.2\t", b"@"]),
    st.integers(10, 80).map(lambda n: b"y" * n),
)


@examples(800)
@given(st.lists(stream_parts, max_size=30), st.lists(st.integers(1, 50), min_size=1, max_size=10),
       st.sampled_from([16, 32, 64]))
# a tag longer than the limit ends after the byte the line is judged on: byte by byte or with
# its LF in one piece, the line gets no tag
@example(parts=[b"@", b"-" * 17, b"\r"], cuts=[1], max_line=16)
@example(parts=[b"@", b"-" * 17, b" x\r\n"], cuts=[50], max_line=16)
def test_splitter_agrees_with_the_model_however_tcp_cuts_the_stream(parts, cuts, max_line) -> None:
    stream = b"".join(parts)
    splitter = LineSplitter(max_line=max_line)
    got: list[bytes | TooLong | Telnet] = []
    i = k = 0
    while i < len(stream):
        n = cuts[k % len(cuts)]
        got += splitter.feed(stream[i : i + n])
        i += n
        k += 1
    assert got == model_lines(stream, max_line)


# ------------------------------------------------------------------------------------ replies


def test_every_command_and_option_of_the_table_is_generated() -> None:
    """The generator covers the whole table, so a new command or option is fuzzed when it lands."""
    import random

    gen = LineGen(random.Random(7))
    seen: dict[str, set[str]] = {name: set() for name in COMMANDS}
    for _ in range(1500):
        for name in COMMANDS:
            req = gen.request(command=name)
            seen[name].update(n for n, _ in req.options)
    for name, cmd in COMMANDS.items():
        if cmd.config is None or cmd.raw:
            continue
        options = {s.name for s in cmd.config.keys().values() if s.option}
        assert options <= seen[name], (name, options - seen[name])


@given(st.sampled_from(["module", "status", "tag"]), st.text(max_size=10))
def test_json_keeps_the_module_whatever_the_keys(key, value) -> None:
    reply = Reply("EGP-RVS-HELP", "OK", {key: value}, "t1")
    back = parse_reply(format_reply_json(reply))
    assert (back.module, back.status, back.tag) == ("EGP-RVS-HELP", "OK", "t1")
