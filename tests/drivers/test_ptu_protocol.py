"""PTU pieces without a line: units, the reply parser, the power reply, motion profiles, garbling."""

from __future__ import annotations

import math

import pytest

from drivers.ptu.emulator import misframe
from drivers.ptu.protocol import ReplyParser, deg_to_pos, encode_command, parse_bound, parse_power, pos_to_deg
from rvs_params.motion import Profile, plan, trapezoid_time

RES = 185.1428


def test_degrees_to_positions_round_to_nearest() -> None:
    assert deg_to_pos(30, RES) == 583  # 583.33
    assert deg_to_pos(-10, RES) == -194  # -194.44
    assert deg_to_pos(-30, RES) == -583
    # 0.5 position = 92.5714 arcsec: halves go away from zero on both sides
    half = 0.5 * RES / 3600
    assert deg_to_pos(half + 1e-9, RES) == 1
    assert deg_to_pos(-half - 1e-9, RES) == -1
    assert pos_to_deg(583, RES) == pytest.approx(29.98285, abs=1e-5)
    assert pos_to_deg(3090, RES) == pytest.approx(158.914, abs=1e-3)


def test_encode_command_adds_the_delimiter_and_rejects_spaces() -> None:
    assert encode_command("pp583") == b"PP583 "
    with pytest.raises(ValueError):
        encode_command("PP 583")
    with pytest.raises(ValueError):
        encode_command("")


def test_parser_terse_verbose_echo_and_line_ends() -> None:
    p = ReplyParser()
    out = p.feed(b"* 583\r\nPP * Current Pan position is 583\rPR5 ! Illegal argument\n")
    assert [(r.ok, r.text) for r in out] == [
        (True, "583"), (True, "Current Pan position is 583"), (False, "Illegal argument")]
    assert [r.number() for r in out] == [583, 583, None]
    # an echoed CR-terminated command is a line of its own and is not a reply
    assert p.feed(b"TP\r* -194\r") and p.skipped_lines == ["TP"]


def test_parser_reassembles_single_bytes() -> None:
    p = ReplyParser()
    replies = []
    for b in b"* 185.1428 seconds arc per Pan position\r\n":
        replies += p.feed(bytes([b]))
    assert len(replies) == 1 and replies[0].number() == pytest.approx(185.1428)


def test_parser_async_limit_hits_glued_or_alone() -> None:
    p = ReplyParser()
    out = p.feed(b"!P\r\n!T!T!P!P*\r\n!P* -3090\r\n! Maximum allowable Pan position is 3090\r\n")
    assert [(r.ok, r.text) for r in out] == [
        (True, ""), (True, "-3090"), (False, "Maximum allowable Pan position is 3090")]
    assert p.async_events == ["!P", "!T", "!T", "!P", "!P", "!P"]


def test_parser_drops_garbled_replies_and_counts_the_noise() -> None:
    p = ReplyParser()
    out = p.feed(b"\xf8\x80x\x00\r\n* 1\xf82\r\n* 7\r\n")
    assert [r.text for r in out] == ["7"]
    assert p.noise_bytes == 4  # 0xf8 0x80 0x00, then 0xf8 inside a reply (the 'x' is printable)
    # junk before the marker is not part of the reply: it is counted, the reply survives
    assert [r.text for r in p.feed(b"\x13\x00 * 583\r\n")] == ["583"] and p.noise_bytes == 6


def test_power_reply_formats() -> None:
    d46 = parse_power("Input 30.0 VDC @ 86 degF")
    assert d46["voltage_v"] == 30.0 and d46["temperature_f"] == 86.0 and d46["temperature_c"] == 30.0
    other = parse_power("12.1 volts, 30 F, 29 F (tilt), 31 F (pan)")
    assert other["voltage_v"] == 12.1 and other["temperatures_f"] == [30.0, 29.0, 31.0]
    with pytest.raises(ValueError):
        parse_power("no numbers")


def test_misframed_bytes_have_no_reply_markers() -> None:
    reply = b"* Current Pan position is 583\r\n! Illegal command\r\n"
    garbled = misframe(reply, 4.0)
    assert garbled and not (set(garbled) & set(b"*!"))
    assert any(b >= 0x80 for b in garbled)
    assert misframe(b"A", 1.0) == b"A"  # same rate: nothing lost


def test_trapezoid_profile_rest_to_rest() -> None:
    prof = Profile.start(0.0, 0.0, 0.0, 583, 1000, 2000)
    assert prof.end == pytest.approx(583 / 1000 + 1000 / 2000)  # 1.083 s: cruise + ramps
    assert prof.end == pytest.approx(trapezoid_time(583, 1000, 2000))
    assert prof.at(0.5) == pytest.approx((250.0, 1000.0))  # end of the ramp: a t^2 / 2
    assert prof.at(prof.end) == (583, 0.0)
    short = Profile.start(0.0, 0.0, 0.0, -194, 1000, 2000)  # triangular: never reaches 1000
    assert short.end == pytest.approx(2 * math.sqrt(194 / 2000))
    assert min(v for _, v in (short.at(t) for t in (0.1, 0.2, 0.3))) < 0


@pytest.mark.parametrize("v0,target", [(800.0, -500.0), (1000.0, 100.0), (-600.0, 900.0), (2500.0, 3000.0)])
def test_profile_replans_from_any_velocity(v0: float, target: float) -> None:
    segs = plan(50.0, v0, target, 1000, 2000)
    prof = Profile(2.0, 50.0, v0, target, segs)
    # continuity: position and velocity are continuous, acceleration bounded, ends at rest on target
    ts = [2.0 + prof_t for prof_t in [i * (prof.end - 2.0) / 400 for i in range(401)]]
    states = [prof.at(t) for t in ts]
    dt = ts[1] - ts[0]
    for (p0, v0_), (p1, v1) in zip(states, states[1:], strict=False):
        assert abs(v1 - v0_) <= 2000 * dt + 1e-6
        assert abs(p1 - p0) <= max(abs(v0_), abs(v1)) * dt + 2000 * dt * dt
    end_p, end_v = Profile(2.0, 50.0, v0, target, segs).at(prof.end - 1e-12)
    assert end_p == pytest.approx(target, abs=1e-3) and end_v == pytest.approx(0, abs=1e-6)


@pytest.mark.parametrize(("text", "bound"), [
    # the manual's wording and the recorded units' (PTU-D46_reply_reference.md)
    ("Pan speed cannot exceed 2902 positions/sec", ("speed", "max", "pan", 2902)),
    ("Tilt speed cannot exceed 4002 pos/sec", ("speed", "max", "tilt", 4002)),
    ("Pan speed cannot exceed 600 pos/sec", ("speed", "max", "pan", 600)),
    ("Motor speed cannot be less than 31 pos/sec", ("speed", "min", None, 31)),
    ("Tilt speed cannot be less than 31 positions/sec", ("speed", "min", "tilt", 31)),
    ("Maximum allowable Tilt position is 601", ("position", "max", "tilt", 601)),
    ("Minimum allowable Tilt position is -903", ("position", "min", "tilt", -903)),
    ("Maximum allowable Pan position is 3091", ("position", "max", "pan", 3091)),
    ("maximum allowable pan position is 3090", ("position", "max", "pan", 3090)),
    ("Illegal command", None),
    ("Pan acceleration must be 1 to 30000 positions/sec^2", None),
])
def test_bounds_stated_in_refusals_are_read_in_every_wording(text: str, bound: tuple | None) -> None:
    got = parse_bound(text)
    assert (None if got is None else (got.kind, got.side, got.axis, got.value)) == bound


def test_speed_replies_read_the_same_in_both_wordings() -> None:
    p = ReplyParser()
    out = p.feed(b"PU * Maximum Pan speed is 1985 positions/sec\r\n"
                 b"PL * Minimum Pan speed is 31 pos/sec\r\n* Current Pan base speed is 1000 positions/sec\r\n")
    assert [r.number() for r in out] == [1985, 31, 1000]
