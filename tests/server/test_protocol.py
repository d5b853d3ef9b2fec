"""The wire grammar of PROTOCOL.md: requests, replies, and the byte stream to lines."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from support.marks import LONG, long

from rvs_server.protocol import (
    Fixed,
    Group,
    LineSplitter,
    ProtocolError,
    Reply,
    Rows,
    TooLong,
    format_reply,
    format_reply_json,
    parse_reply,
    parse_request,
    show_controls,
    valid_stem,
)

# the default run a quarter of the examples named, RVS_LONG=1 five times them (the round trips of
# every reply and request shape: the wire's contract)
SCALE = 5 if LONG else 0.25


def opts(line: str) -> list[tuple[str, object]]:
    req = parse_request(line)
    assert req is not None
    return req.options


def test_thesis_example_lines() -> None:
    req = parse_request("move-ptu -pan -30 -tilt -20")
    assert req is not None and req.command == "move-ptu"
    assert req.options == [("pan", "-30"), ("tilt", "-20")]
    req = parse_request("@g7 grab-tof -output TestImage -type amplitude")
    assert req is not None and req.tag == "g7"
    assert req.options == [("output", "TestImage"), ("type", "amplitude")]
    assert opts("dem-full-tof -range -150,150,-50,-15 -name site1") == [
        ("range", "-150,150,-50,-15"), ("name", "site1")]


def test_dash_forms_and_flags() -> None:
    assert opts("x --output a \u2013type b -auto") == [("output", "a"), ("type", "b"), ("auto", True)]
    assert opts("x -auto -goal 3.5,-2") == [("auto", True), ("goal", "3.5,-2")]
    assert opts("x -a=1 --b=-2.5 -c=\"q r\"") == [("a", "1"), ("b", "-2.5"), ("c", "q r")]
    assert opts("x -Max-Deviation 0.2") == [("max_deviation", "0.2")]


def test_numbers_are_values_not_options() -> None:
    assert opts("x -pan -1.5 -range -90,90,-45,-10") == [("pan", "-1.5"), ("range", "-90,90,-45,-10")]
    assert opts('x -name "-look"') == [("name", "-look")]


def test_quoted_strings_and_escapes() -> None:
    assert opts(r'x -msg "say \"hi\" \\ there"') == [("msg", 'say "hi" \\ there')]
    with pytest.raises(ProtocolError) as e:
        parse_request('x -msg "open')
    assert e.value.code == "E_SYNTAX"
    with pytest.raises(ProtocolError):
        parse_request(r'x -msg "bad \q"')


def test_module_id_and_case() -> None:
    req = parse_request("EGP-RVS-GRAB-TOF -TYPE z")
    assert req is not None and req.command == "egp-rvs-grab-tof" and req.options == [("type", "z")]


def test_blank_comment_positional_and_tags() -> None:
    assert parse_request("") is None
    assert parse_request("   \t ") is None
    assert parse_request("  # a comment") is None
    req = parse_request("help grab-tof")
    assert req is not None and req.positional == ["grab-tof"]
    for bad in ("@ status", "@" + "x" * 33 + " status", "@a/b status", "@t"):
        with pytest.raises(ProtocolError) as e:
            parse_request(bad)
        assert e.value.code == "E_SYNTAX"
    with pytest.raises(ProtocolError) as e:
        parse_request("x -a 1 stray")
    assert e.value.code == "E_ARG"


def test_stems() -> None:
    for ok in ("TestImage", "site1", "a.b-c_d", "x" * 64):
        assert valid_stem(ok)
    for bad in ("", ".hidden", "../etc/passwd", "/abs", "a/b", "a..b", "x" * 65, "a b", "a\x00b", "caf\u00e9"):
        assert not valid_stem(bad)


def test_reply_format_text_and_json() -> None:
    r = Reply("EGP-RVS-MOVE-PTU", "OK", {"job": 1, "pan": Fixed(-30, 3), "ok": True, "m": 'a "b"\nc'}, "g7")
    line = format_reply(r)
    assert line == 'EGP-RVS-MOVE-PTU OK tag=g7 job=1 pan=-30.000 ok=true m="a \\"b\\"\\nc"'
    obj = json.loads(format_reply_json(r))
    assert obj == {"module": "EGP-RVS-MOVE-PTU", "status": "OK", "tag": "g7", "job": 1, "pan": -30.0,
                   "ok": True, "m": 'a "b"\nc'}
    assert list(obj)[:3] == ["module", "status", "tag"]
    back = parse_reply(line)
    assert back.tag == "g7" and back.fields["m"] == 'a "b"\nc' and back.fields["pan"] == "-30.000"


keys = st.from_regex(r"[a-z][a-z0-9_]{0,12}", fullmatch=True).filter(lambda k: k != "tag")
values = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\r"), max_size=30)
replies = st.builds(
    Reply,
    module=st.from_regex(r"(RVS|EGP-RVS-[A-Z0-9-]{1,20})", fullmatch=True),
    status=st.sampled_from(["ACK", "PROGRESS", "OK", "ERROR", "EVENT"]),
    fields=st.dictionaries(keys, values, max_size=6),
    tag=st.none() | st.from_regex(r"[A-Za-z0-9_.:\-]{1,32}", fullmatch=True),
)


@long
@settings(max_examples=int(400 * SCALE), deadline=None)
@given(replies)
def test_reply_round_trip(reply: Reply) -> None:
    # text shows control characters in caret notation (^L), JSON carries them exactly
    shown = Reply(reply.module, reply.status, {k: show_controls(v) for k, v in reply.fields.items()}, reply.tag)
    assert parse_reply(format_reply(reply)) == shown
    assert parse_reply(format_reply_json(reply)) == reply


@long
@settings(max_examples=int(1500 * SCALE), deadline=None)
@given(st.binary(max_size=200))
def test_arbitrary_bytes_only_raise_protocol_errors(data: bytes) -> None:
    text = data.decode("utf-8", "replace")
    try:
        req = parse_request(text)
    except ProtocolError as exc:
        assert exc.code in ("E_SYNTAX", "E_ARG") and exc.message
    else:
        assert req is None or req.command


@long
@settings(max_examples=int(300 * SCALE), deadline=None)
@given(st.lists(st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters='"\\\n\r'), max_size=12),
                min_size=1, max_size=6))
def test_quoted_values_survive(words: list[str]) -> None:
    line = "cmd " + " ".join(f'-k{i} "{w}"' for i, w in enumerate(words))
    assert opts(line) == [(f"k{i}", w) for i, w in enumerate(words)]


def test_splitter_crlf_iac_and_chunks() -> None:
    s = LineSplitter()
    assert s.feed(b"sta") == []
    assert s.feed(b"tus\r\nhe") == [b"status"]
    # IAC DO ECHO (3 bytes), IAC NOP (2 bytes), split across feeds
    assert s.feed(b"lp\xff") == []
    assert s.feed(b"\xfd\x01 x\xff\xf1\n") == [b"help x"]
    assert s.feed(b"\n\r\n") == [b"", b""]


def test_splitter_too_long_discards_rest() -> None:
    s = LineSplitter(max_line=16)
    out = s.feed(b"a" * 10)
    out += s.feed(b"b" * 10)
    out += s.feed(b"c" * 100 + b"\nnext\n")
    assert out == [TooLong(), b"next"]
    assert LineSplitter(max_line=4).feed(b"abcd\r\nabcde\n") == [b"abcd", TooLong()]


@long
@settings(max_examples=int(200 * SCALE), deadline=None)
@given(st.lists(st.binary(min_size=0, max_size=50).filter(lambda b: b"\n" not in b and b"\xff" not in b),
                min_size=1, max_size=8), st.integers(1, 7))
def test_splitter_chunking_does_not_matter(lines: list[bytes], step: int) -> None:
    stream = b"".join(line + b"\n" for line in lines)
    s = LineSplitter(max_line=4096)
    out: list[bytes | None] = []
    for i in range(0, len(stream), step):
        out += s.feed(stream[i : i + step])
    telnet = [line.replace(b"\r\x00", b"\r") for line in lines]  # CR NUL is a bare CR
    assert out == [line[:-1] if line.endswith(b"\r") else line for line in telnet]


def test_json_values_are_the_text_values_typed() -> None:
    r = Reply("X", "OK", {
        "pan": Fixed(29.98349, 3), "g": 0.123456789, "n": np.int64(3), "b": np.bool_(True), "absent": None,
        "nan": float("nan"), "rows": Rows([(Fixed(1, 3), Fixed(2, 3), Fixed(45.678, 2))] * 2),
        "settings": Group({"height": False, "ptu": {"backend": "sim"}}), "worst": Fixed(0.85, 3)})
    assert format_reply(r) == ("X OK pan=29.983 g=0.123457 n=3 b=true absent=none nan=nan "
                               "rows=1.000,2.000,45.68,1.000,2.000,45.68 height=false ptu_backend=sim worst=0.850")
    assert json.loads(format_reply_json(r)) == {
        "module": "X", "status": "OK", "pan": 29.983, "g": 0.123457, "n": 3, "b": True, "absent": None,
        "nan": None, "rows": [[1.0, 2.0, 45.68], [1.0, 2.0, 45.68]],
        "settings": {"height": False, "ptu": {"backend": "sim"}}, "worst": "0.850"}
