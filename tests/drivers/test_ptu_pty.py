"""The PTU client against the PTU-D46 emulator through a real pseudo-terminal (os.openpty).

Every behaviour runs against both emulator flavours: ``manual`` (the D46 manual's replies) and
``field`` (a recorded real unit's: "pos/sec", limits a few counts off, lower speed ceilings;
shared/realdata/ptu/PTU-D46_reply_reference.md). Expectations come from the flavour's own table,
so a client that hard-codes the manual's figures fails the field runs. The field variants of the
tests that run in wall-clock time (time_scale > 0) only run in the long suite.
"""

from __future__ import annotations

import threading

import pytest
from ptu_rig import bench
from support.marks import LONG, long_only

from drivers.base import DeviceError
from drivers.ptu.client import MoveInterrupted, PtuClient
from drivers.ptu.emulator import FLAVOURS, Flavour
from rvs_params.motion import trapezoid_time

OPEN_SEQUENCE = ["FT", "ED", "CI", "I", "PR", "TR", "PN", "PX", "TN", "TX", "PL", "PU", "TL", "TU"]
RES = 185.1428


@pytest.fixture(params=list(FLAVOURS))
def flavour(request: pytest.FixtureRequest) -> Flavour:
    return FLAVOURS[request.param]


# the field run of a wall-clock test: the manual run keeps the behaviour covered in the default suite
SLOW = pytest.fixture(params=["manual", pytest.param("field", marks=long_only())])


@SLOW
def slow_flavour(request: pytest.FixtureRequest) -> Flavour:
    return FLAVOURS[request.param]


def deg(pos: int) -> float:
    return pos * RES / 3600


def test_open_sequence_leaves_the_unit_terse_without_echo(flavour: Flavour) -> None:
    with bench(flavour=flavour) as (emu, ptu):
        assert emu.commands[: len(OPEN_SEQUENCE)] == OPEN_SEQUENCE
        # the unit powered up verbose with echo on and a banner; the client changed both
        assert emu.verbose is False and emu.echo is False
        assert emu.tx.startswith(flavour.firmware.encode())
        assert ptu.resolution == {"pan": RES, "tilt": RES}
        assert ptu.bounds == flavour.limits  # read from the unit, never the manual's constants
        assert ptu.speed_bounds == flavour.speed_bounds
        lim = ptu.limits()
        assert lim["pan"]["max_deg"] == pytest.approx(deg(flavour.limits["pan"][1]), abs=1e-9)
        assert lim["tilt"]["min_deg"] == pytest.approx(deg(flavour.limits["tilt"][0]), abs=1e-9)
        assert lim["tilt"]["max_deg"] == pytest.approx(deg(flavour.limits["tilt"][1]), abs=1e-9)
        assert lim["pan"]["speed_max"] == flavour.speed_bounds["pan"][1]


def test_manual_and_field_bounds_are_those_of_the_reference() -> None:
    """The figures the two flavours stand for (PTU-D46_reply_reference.md), pinned here so an
    edit of the emulator's table cannot quietly make the field flavour the manual again."""
    assert FLAVOURS["manual"].limits == {"pan": (-3090, 3090), "tilt": (-907, 604)}
    assert FLAVOURS["field"].limits == {"pan": (-3090, 3091), "tilt": (-903, 601)}
    assert FLAVOURS["field"].speed_bounds == {"pan": (31, 600), "tilt": (31, 4002)}
    assert FLAVOURS["field"].speed_unit == "pos/sec" and FLAVOURS["manual"].speed_unit == "positions/sec"


def test_a_configured_speed_above_the_units_ceiling_is_brought_inside_it(flavour: Flavour) -> None:
    """drivers.ptu.speed 1000 is above the field unit's pan ceiling of 600: the open must not
    fail on it; the client sets the ceiling and says so in the snapshot."""
    with bench(flavour=flavour, client={"speed": 1000}) as (emu, ptu):
        pan_hi, tilt_hi = flavour.speed_bounds["pan"][1], flavour.speed_bounds["tilt"][1]
        assert ptu.get_speed() == (min(1000, pan_hi), min(1000, tilt_hi))
        clamped = ptu.snapshot()["speed_clamped"]
        if pan_hi < 1000:
            assert clamped == f"pan 1000 -> {pan_hi} positions/s (unit bounds 31..{pan_hi})"
        else:
            assert clamped is None


def test_move_sends_pp583_and_tp_minus_194(flavour: Flavour) -> None:
    with bench(flavour=flavour) as (emu, ptu):
        start = len(emu.rx)
        pan, tilt = ptu.move(30, -10)
        sent = bytes(emu.rx[start:])
        assert sent == b"PP583 TP-194 A PP TP "
        assert emu.positions() == (583, -194)
        assert pan == pytest.approx(583 * 185.1428 / 3600) and tilt == pytest.approx(-194 * 185.1428 / 3600)
        snap = ptu.snapshot()
        assert snap["pan_pos"] == 583 and snap["tilt_pos"] == -194 and snap["moving"] is False


def test_moves_reach_the_units_own_limits_exactly(flavour: Flavour) -> None:
    """Up to the last count the unit allows (3091 on the field unit, one past the manual), and
    not one count further."""
    with bench(flavour=flavour) as (emu, ptu):
        (plo, phi), (tlo, thi) = flavour.limits["pan"], flavour.limits["tilt"]
        assert ptu.move(deg(phi), deg(tlo)) == pytest.approx((deg(phi), deg(tlo)))
        assert emu.positions() == (phi, tlo)
        assert ptu.move(deg(plo), deg(thi)) == pytest.approx((deg(plo), deg(thi)))
        with pytest.raises(DeviceError) as err:
            ptu.move(deg(phi + 1), 0)
        assert f"positions {plo}..{phi}" in err.value.message


def test_limits_are_checked_before_anything_is_sent(flavour: Flavour) -> None:
    with bench(flavour=flavour) as (emu, ptu):
        before = list(emu.commands)
        with pytest.raises(DeviceError) as err:
            ptu.move(170, 0)
        assert err.value.device == "ptu" and f"maximum {deg(flavour.limits['pan'][1]):.2f} deg" in err.value.message
        with pytest.raises(DeviceError) as err:
            ptu.move(0, -50)
        assert f"tilt minimum {deg(flavour.limits['tilt'][0]):.2f} deg" in err.value.message
        with pytest.raises(DeviceError):
            ptu.move(10, 40)  # pan fine, tilt beyond +31.06: neither axis moves
        assert emu.commands == before and emu.positions() == (0, 0)


def test_device_error_replies_carry_the_units_text(flavour: Flavour) -> None:
    unit = flavour.speed_unit
    pan_hi = flavour.speed_bounds["pan"][1]
    with bench(flavour=flavour) as (emu, ptu):
        with pytest.raises(DeviceError) as err:
            ptu.set_speed(5000, 200)
        assert err.value.message == f"the PTU refused PS5000: Pan speed cannot exceed {pan_hi} {unit}"
        with pytest.raises(DeviceError) as err:
            ptu.set_speed(200, 10)
        floor = "Tilt speed" if flavour.name == "manual" else "Motor speed"
        assert err.value.message == f"the PTU refused TS10: {floor} cannot be less than 31 {unit}"
        # the emulator enforces its own bounds too (raw bypasses the client's check)
        phi, tlo = flavour.limits["pan"][1], flavour.limits["tilt"][0]
        assert ptu.raw("PP4000") == f"! Maximum allowable Pan position is {phi}"
        assert ptu.raw("TP-1000") == f"! Minimum allowable Tilt position is {tlo}"
        assert ptu.raw("XYZ") == "! Illegal command"
        ptu.set_speed(pan_hi, 500)
        ptu.set_acceleration(4000, 1500)
        assert ptu.get_speed() == (pan_hi, 500) and ptu.get_acceleration() == (4000, 1500)


def test_a_refusal_that_states_a_bound_corrects_the_clients_belief(flavour: Flavour) -> None:
    """A unit whose limit moved (re-measured by a reset, or a unit swapped on the same cable)
    refuses a target the client thought allowed; the bound in the refusal is believed from
    then on, so the next try is refused before anything is sent, with the unit's figure."""
    with bench(flavour=flavour) as (emu, ptu):
        phi = flavour.limits["pan"][1]
        ptu.bounds["pan"] = (ptu.bounds["pan"][0], phi + 5)  # stale: five counts too generous
        with pytest.raises(DeviceError) as err:
            ptu.move(deg(phi + 3), None)
        assert err.value.message == f"the PTU refused PP{phi + 3}: Maximum allowable Pan position is {phi}"
        assert ptu.bounds["pan"][1] == phi
        sent = len(emu.commands)
        with pytest.raises(DeviceError) as err:
            ptu.move(deg(phi + 3), None)
        assert "beyond the pan maximum" in err.value.message and len(emu.commands) == sent
        ptu.speed_bounds["tilt"] = (31, 99_999)
        with pytest.raises(DeviceError):
            ptu.set_speed(None, 90_000)
        assert ptu.speed_bounds["tilt"] == flavour.speed_bounds["tilt"]


def test_power_and_firmware(flavour: Flavour) -> None:
    with bench(flavour=flavour, supply_v=24.0, temperature_f=95) as (emu, ptu):
        power = ptu.power_status()  # "Input 24.0 VDC @ 95 degF" (manual) or "Input 24 VDC @ 95 degF"
        assert power["voltage_v"] == 24.0 and power["temperature_f"] == 95
        assert power["temperature_c"] == pytest.approx(35.0)
        assert ptu.firmware() == flavour.firmware


def test_client_copes_with_a_unit_left_verbose_with_echo(flavour: Flavour) -> None:
    """Verbose replies word the same figures differently per unit ("positions/sec" or
    "pos/sec", "Pan" or "pan"): the client reads the number, not the sentence."""
    with bench(flavour=flavour) as (emu, ptu):
        assert ptu.raw("FV") == "*" and ptu.raw("EE") == "*"
        assert emu.verbose and emu.echo
        assert ptu.query_number("PR") == pytest.approx(RES)
        assert ptu.query_number("PN") == flavour.limits["pan"][0]
        assert ptu.query_number("TX") == flavour.limits["tilt"][1]
        assert ptu.query_number("PU") == flavour.speed_bounds["pan"][1]
        assert ptu.raw("PU") == f"* Maximum Pan speed is {flavour.speed_bounds['pan'][1]} {flavour.speed_unit}"
        ptu.set_speed(500, 500)
        assert ptu.get_speed() == (500, 500)
        assert ptu.raw("PS") == f"* Desired Pan speed is 500 {flavour.speed_unit}"
        assert ptu.move(-20, 15) == pytest.approx((deg(-389), deg(292)))
        pan = "pan" if flavour.lower_case_position else "Pan"
        assert ptu.raw("PP") == f"* Current {pan} position is -389"


def test_open_against_a_unit_in_verbose_echo_mode_with_cr_delimited_input() -> None:
    """A unit left verbose with echo on by someone's terminal session, and half a command in
    its buffer: the leading delimiter flushes it and the handshake still lands."""
    with bench(open_client=False) as (emu, ptu):
        emu.write_raw(b"* Current Pan position is 12\r\n")  # stale output from a previous session
        ptu.open()
        assert emu.echo is False and ptu.position() == (0.0, 0.0)


@pytest.mark.parametrize("eol", [b"\r", b"\n", b"\r\n"], ids=["CR", "LF", "CRLF"])
def test_line_endings(eol: bytes) -> None:
    with bench(eol=eol) as (emu, ptu):
        assert ptu.move(30, -10) == pytest.approx((29.98285, -9.97714), abs=1e-5)
        ptu.raw("FV")
        assert ptu.position() == pytest.approx((29.98285, -9.97714), abs=1e-5)


def test_replies_split_into_single_bytes() -> None:
    with bench(chunk=1) as (emu, ptu):
        assert ptu.move(30, -10) == pytest.approx((29.98285, -9.97714), abs=1e-5)
        assert ptu.query_number("TR") == pytest.approx(185.1428)


def test_async_limit_notifications_in_the_stream() -> None:
    with bench() as (emu, ptu):
        ptu.move(30, -10)
        emu.prefix_next_reply(b"!P\r\n")
        assert ptu.position()[0] == pytest.approx(29.98285, abs=1e-5)
        emu.prefix_next_reply(b"!T")  # glued to the reply, no line end
        assert ptu.query_number("TP") == -194
        snap = ptu.snapshot()
        assert snap["limit_hits"] == 2 and snap["last_async"] == "!T"


def test_stale_bytes_before_a_reply_are_discarded() -> None:
    with bench() as (emu, ptu):
        ptu.move(30, -10)
        emu.write_raw(b"* 9999\r\n* Current Tilt pos")  # a late reply and half a line
        assert ptu.query_number("PP") == 583
        emu.prefix_next_reply(b"x\x13 junk ")  # junk on the reply's own line
        assert ptu.query_number("TP") == -194


def test_reset_runs_into_the_limits_and_home(flavour: Flavour) -> None:
    with bench(flavour=flavour) as (emu, ptu):
        ptu.move(30, -10)
        assert ptu.reset() == (0.0, 0.0)
        assert b"!T!T!P!P*" in bytes(emu.tx)
        assert ptu.snapshot()["limit_hits"] == 4
        r = len(emu.commands) - 1 - emu.commands[::-1].index("R")
        assert emu.commands[r + 1 :] == ["PN", "PX", "TN", "TX", "PP", "TP"]  # bounds measured anew
        reached = {(m["axis"], m["to"]) for m in emu.moves}
        (plo, phi), (tlo, thi) = flavour.limits["pan"], flavour.limits["tilt"]
        assert {("tilt", thi), ("tilt", tlo), ("pan", phi), ("pan", plo)} <= reached
        assert ptu.bounds == flavour.limits


def test_silent_unit_times_out_with_a_helpful_error() -> None:
    with bench(open_client=False, fault="silent", client={"timeout": 0.3}) as (emu, ptu):
        with pytest.raises(DeviceError) as err:
            ptu.open()
        assert err.value.device == "ptu"
        assert "no reply to FT within 0.3s; check cable, power and baud rate" in err.value.message
        assert not ptu.is_open
        assert emu.commands == [] and b"FT " in bytes(emu.rx)  # it heard, it never answered


def test_unit_going_silent_after_open() -> None:
    with bench(client={"timeout": 0.3}) as (emu, ptu):
        emu.inject_fault("silent")
        with pytest.raises(DeviceError) as err:
            ptu.move(30, -10)
        assert "no reply to PP583 within 0.3s" in err.value.message
        emu.inject_fault(None)
        assert ptu.move(30, -10) == pytest.approx((29.98285, -9.97714), abs=1e-5)


def test_wrong_baud_rate_garbage_is_named() -> None:
    with bench(open_client=False, fault="garbage", client={"timeout": 0.3}) as (emu, ptu):
        with pytest.raises(DeviceError) as err:
            ptu.open()
        msg = err.value.message
        assert "unreadable bytes" in msg and "baud rate mismatch" in msg and "within 0.3s" in msg
        assert "9600" in msg


def test_stalled_move_times_out_halts_and_recovers(flavour: Flavour) -> None:
    with bench(flavour=flavour, client={"move_timeout": 0.3}) as (emu, ptu):
        emu.inject_fault("stall")
        with pytest.raises(DeviceError) as err:
            ptu.move(30, -10)
        msg = err.value.message
        assert "did not finish within 0.3s" in msg and "stalled" in msg and "pan 0.00 deg" in msg
        assert emu.commands[-3:] == ["H", "PP", "TP"]
        emu.inject_fault(None)
        assert ptu.move(30, -10) == pytest.approx((29.98285, -9.97714), abs=1e-5)


def test_unit_dying_mid_move_is_a_line_fault_not_a_stall() -> None:
    with bench(time_scale=1.0, client={"timeout": 0.2}) as (emu, ptu):
        ptu.move(150, 0, wait=False)  # about 3.4 s of motion
        assert ptu.snapshot()["moving"] is True
        emu.inject_fault("silent")
        with pytest.raises(DeviceError) as err:
            ptu.await_motion(timeout=0.3)
        msg = err.value.message
        assert "no reply to A within 0.3s and none to H" in msg and "check cable, power and baud rate" in msg
        assert ptu.snapshot()["moving"] is False


@pytest.mark.parametrize("time_scale", [0.0, 0.02])
def test_move_takes_the_trapezoid_time_in_simulated_time(time_scale: float, flavour: Flavour) -> None:
    if time_scale > 0 and flavour.name != "manual" and not LONG:
        pytest.skip("the field flavour's wall-clock run is in the long suite (RVS_LONG=1)")
    v = min(1000, flavour.speed_bounds["pan"][1])  # the field unit's pan ceiling is 600
    with bench(flavour=flavour, time_scale=time_scale, speed=1000, acceleration=2000,
               client={"speed": 1000, "acceleration": 2000}) as (emu, ptu):
        t0 = emu.sim_time
        ptu.move(30, 0)
        pan = [m for m in emu.moves if m["axis"] == "pan"][-1]
        # at or below the base speed (the D46's default 1000 positions/s) an axis starts and stops at once
        assert pan["duration"] == pytest.approx(583 / v, abs=0.005)
        assert pan["duration"] == pytest.approx(trapezoid_time(583, v, 2000, base=1000), abs=0.005)
        assert pan["t_start"] >= t0 and emu.sim_time >= pan["t_end"]
        assert ptu.raw("PB0") == "*" and ptu.raw("TB0") == "*"  # from rest: ramps of v/a each, cruise for the rest
        ptu.set_speed(500, 500)
        ptu.move(0, 0)
        back = [m for m in emu.moves if m["axis"] == "pan"][-1]
        assert back["duration"] == pytest.approx(trapezoid_time(583, 500, 2000), abs=0.005)
        assert back["duration"] == pytest.approx(583 / 500 + 500 / 2000, abs=0.005)


def test_halt_from_another_thread_interrupts_a_move(slow_flavour: Flavour) -> None:
    # A 150 deg pan takes about 4 s of wall time; the halt comes once it is past 5 deg (100
    # counts, after ~0.5 s), so the test thread may lag 3 s on a busy machine before the move ends.
    with bench(flavour=slow_flavour, time_scale=0.2) as (emu, ptu):
        result: dict[str, object] = {}

        def mover() -> None:
            try:
                result["pos"] = ptu.move(150, 0)
            except MoveInterrupted as exc:
                result["interrupted"] = exc

        t = threading.Thread(target=mover)
        t.start()
        assert emu.wait_for(lambda e: "A" in e.commands and e.positions()[0] > 100, timeout=60)
        ptu.halt()
        t.join(timeout=5.0)
        exc = result.get("interrupted")
        assert isinstance(exc, MoveInterrupted), result
        assert exc.position is not None and 0 < exc.position[0] < 150
        assert "H" in emu.commands
        assert emu.positions()[0] == pytest.approx(exc.position[0] * 3600 / 185.1428, abs=1)
        assert not ptu.snapshot()["moving"]


def test_cancel_event_interrupts_the_await(slow_flavour: Flavour) -> None:
    with bench(flavour=slow_flavour, time_scale=0.2) as (emu, ptu):  # as above: the cancel comes ~3 s before the move would end
        cancel = threading.Event()
        threading.Thread(
            target=lambda: emu.wait_for(lambda e: "A" in e.commands and e.positions()[0] < -100, 60)
            and cancel.set()).start()
        with pytest.raises(MoveInterrupted) as err:
            ptu.move(-150, 0, cancel=cancel)
        assert -150 < err.value.position[0] < 0
        # the line is in step afterwards: the next exchange gets its own reply
        assert ptu.move(0, 0) == (0.0, 0.0)


def test_a_cancelled_await_ends_at_the_halts_ack_and_the_next_command_waits_for_the_stop() -> None:
    # a slow acceleration (250 pos/s^2) makes the deceleration after the halt last about a second
    # (base speed 0: the deceleration runs down from the full speed)
    with bench(time_scale=1.0, acceleration=250, base_speed=0,
               client={"acceleration": 250, "move_timeout": 60}) as (emu, ptu):
        cancel = threading.Event()
        threading.Thread(target=lambda: emu.wait_for(lambda e: "A" in e.commands and e.positions()[0] > 200, 60)
                         and cancel.set(), daemon=True).start()
        with pytest.raises(MoveInterrupted) as err:
            ptu.move(150, 0, cancel=cancel)
        assert emu.axes["P"].moving()  # the wait ended while the pan axis was still slowing down
        assert ptu.snapshot()["moving"] is True
        halted_at = err.value.position[0]
        assert 200 * 185.1428 / 3600 < halted_at < 150
        pan, _ = ptu.position()  # first the move's last reply, then where the axes stopped
        assert not emu.axes["P"].moving() and not ptu.snapshot()["moving"]
        assert pan > halted_at and emu.positions()[0] == pytest.approx(pan * 3600 / 185.1428, abs=1)
        assert ptu.command("PP").number() == emu.positions()[0]  # the line is in step


def test_any_pyserial_url_works_and_a_dead_loop_times_out() -> None:
    ptu = PtuClient("loop://", 9600, timeout=0.2)
    with pytest.raises(DeviceError) as err:
        ptu.open()
    assert "no reply to FT within 0.2s" in err.value.message and "loop://" in err.value.message
    missing = PtuClient("/dev/does-not-exist-ptu", 9600, timeout=0.2)
    with pytest.raises(DeviceError) as err:
        missing.open()
    assert "cannot open serial port /dev/does-not-exist-ptu" in err.value.message
    assert "dialout" in err.value.message


def test_on_an_instant_world_clock_a_move_nobody_awaits_overlaps_what_moves_the_clock_meanwhile() -> None:
    # The see loop sends the next frame's look with the cycle's motion and awaits it before the
    # frame: the mast slews while the wheels turn. A move sent without waiting leaves the world's
    # clock where it was; an await moves it on to where the axes stopped; an await after the rover
    # drove past that costs nothing more.
    from drivers.sim.clock import SimClock

    clock = SimClock(0.0)
    with bench(clock=clock) as (emu, ptu):
        t0 = clock.now()
        ptu.move(30, 0, wait=False)
        assert clock.now() == pytest.approx(t0, abs=1e-9)
        ptu.await_motion()
        pan = [m for m in emu.moves if m["axis"] == "pan"][-1]
        assert pan["duration"] > 0.3
        assert clock.now() == pytest.approx(t0 + pan["duration"], abs=1e-3)
        t1 = clock.now()
        ptu.move(0, 0, wait=False)
        clock.advance_to(t1 + 5.0)  # the rover drove 5 s meanwhile
        ptu.await_motion()
        back = [m for m in emu.moves if m["axis"] == "pan"][-1]
        assert back["t_start"] == pytest.approx(t1, abs=1e-3) and back["t_end"] < t1 + 5.0
        assert clock.now() == pytest.approx(t1 + 5.0, abs=1e-3)
        ptu.move(30, 0)  # awaited: the caller's wait takes the move's time
        assert clock.now() == pytest.approx(t1 + 5.0 + pan["duration"], abs=1e-3)
