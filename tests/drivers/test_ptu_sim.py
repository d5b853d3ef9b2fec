"""The PTU device (create/open/status/faults) with the sim backend: the emulator on a pty."""

from __future__ import annotations

import threading

import pytest
from ptu_rig import bench

from drivers.base import Device, DeviceError
from drivers.ptu import BACKENDS, MoveInterrupted, Ptu, create

FAST = {"backend": "sim", "time_scale": 0.0, "timeout": 0.3, "move_timeout": 1.0}


class FakeWorld:
    def __init__(self) -> None:
        self.calls: list[tuple[float, float]] = []

    def set_ptu(self, pan_deg: float, tilt_deg: float) -> None:
        self.calls.append((pan_deg, tilt_deg))


@pytest.fixture
def ptu() -> Ptu:
    dev = create(dict(FAST))
    yield dev
    dev.close()


def test_create_gives_a_device() -> None:
    dev = create(dict(FAST))
    assert isinstance(dev, Device) and dev.name == "ptu" and dev.backend == "sim"
    assert dev.status()["open"] is False  # create does not open; first use or open() does
    with pytest.raises(DeviceError) as err:
        create({"backend": "usb"})
    assert err.value.device == "ptu" and f"registered: {', '.join(BACKENDS.names())}" in err.value.message


def test_sim_backend_moves_the_head_in_the_world_as_it_turns() -> None:
    world = FakeWorld()
    dev = create({**FAST, "time_scale": 0.05}, world)
    try:
        assert dev.move(30, -10) == pytest.approx((29.98285, -9.97714), abs=1e-5)
        assert world.calls[0] == (0.0, 0.0)  # power-up pose
        assert world.calls[-1] == pytest.approx((29.98285, -9.97714), abs=1e-5)
        pans = [p for p, _ in world.calls]
        assert len(world.calls) > 3  # intermediate poses while moving, not just the end
        assert pans == sorted(pans) and any(0 < p < 29.9 for p in pans)
    finally:
        dev.close()


def test_sim_backend_with_the_simulated_world() -> None:
    from drivers.sim.world import World

    world = World.from_scene("office", seed=0)
    dev = create(dict(FAST), world)
    try:
        dev.move(-45, 20)
        assert world.ptu() == pytest.approx((-875 * 185.1428 / 3600, 389 * 185.1428 / 3600), abs=1e-6)
    finally:
        dev.close()


def test_status_is_a_snapshot_that_never_waits_for_a_move() -> None:
    # slow motion (a 100 deg move takes ~6 s; halted right after the checks): a test thread
    # lagging on a busy machine must still find the move under way
    dev = create({**FAST, "time_scale": 0.1})
    try:
        dev.open()
        emu = dev.emulator
        done = threading.Event()

        def mover() -> None:
            try:
                dev.move(100, 0)
            except MoveInterrupted:
                pass
            done.set()

        t = threading.Thread(target=mover)
        t.start()
        assert emu.wait_for(lambda e: "A" in e.commands, timeout=60)  # a safety net
        st = dev.status()  # the move holds the serial line right now
        assert st["moving"] is True and not done.is_set()
        assert st["target_pan_deg"] == pytest.approx(1944 * 185.1428 / 3600)
        assert st["backend"] == "sim" and st["port"].startswith("/dev/") and st["baudrate"] == 9600
        assert st["limits"]["pan"]["max"] == 3090 and st["resolution_arcsec"]["tilt"] == 185.1428
        dev.halt()
        t.join(5.0)
        assert done.is_set() and dev.status()["moving"] is False
    finally:
        dev.close()


def test_faults_surface_as_device_errors_and_recover(ptu: Ptu) -> None:
    ptu.move(10, 0)
    ptu.inject_fault("silent")
    with pytest.raises(DeviceError) as err:
        ptu.position()
    assert err.value.device == "ptu" and "within 0.3s; check cable, power and baud rate" in err.value.message
    assert "no reply to PP" in ptu.status()["last_error"] and ptu.status()["fault"] == "silent"
    with pytest.raises(DeviceError):
        ptu.reinit()  # the unit stays dead across a reinit, like unplugged hardware

    ptu.inject_fault("garbage")
    with pytest.raises(DeviceError) as err:
        ptu.reinit()
    assert "baud rate mismatch" in err.value.message

    ptu.inject_fault(None)
    ptu.reinit()
    assert ptu.position() == pytest.approx((10 * 1.0, 0.0), abs=0.03)  # kept its pose: 194 positions
    assert ptu.status()["last_error"] is None

    ptu.inject_fault("stall")
    with pytest.raises(DeviceError) as err:
        ptu.move(30, 0)
    assert "did not finish within 1s" in err.value.message
    ptu.inject_fault("none")
    assert ptu.move(30, 0)[0] == pytest.approx(29.98285, abs=1e-5)


def test_reinit_redoes_the_handshake_and_reset_goes_home(ptu: Ptu) -> None:
    ptu.move(20, 10)
    ptu.reinit()
    assert ptu.emulator.commands.count("FT") == 2
    assert ptu.position() == pytest.approx((20.0, 10.0), abs=0.03)
    assert ptu.reset() == (0.0, 0.0)
    assert ptu.check()["pan_deg"] == 0.0 and ptu.check()["voltage_v"] == 30.0


def test_fault_injection_is_checked(ptu: Ptu) -> None:
    with pytest.raises(DeviceError):
        ptu.inject_fault("smoke")
    serial_dev = create({"backend": "serial", "port": "/dev/does-not-exist-ptu", "timeout": 0.2})
    with pytest.raises(DeviceError) as err:
        serial_dev.inject_fault("silent")
    assert "sim backend" in err.value.message


def test_serial_backend_on_any_port() -> None:
    with bench(open_client=False) as (emu, client):
        dev = create({"backend": "serial", "port": client.port, "timeout": 0.3, "time_scale": 0})
        try:
            assert dev.move(30, -10) == pytest.approx((29.98285, -9.97714), abs=1e-5)
            assert "PP583" in emu.commands and dev.status()["port"] == client.port
        finally:
            dev.close()
    missing = create({"backend": "serial", "port": "/dev/does-not-exist-ptu"})
    with pytest.raises(DeviceError) as err:
        missing.open()
    assert "cannot open serial port /dev/does-not-exist-ptu" in err.value.message
    assert missing.status()["last_error"] == err.value.message


def test_close_stops_the_emulator(ptu: Ptu) -> None:
    ptu.open()
    emu = ptu.emulator
    assert emu.running
    ptu.close()
    assert not emu.running and ptu.status()["open"] is False
    assert ptu.position() == (0.0, 0.0)  # used again: a fresh unit powers up at home


@pytest.mark.parametrize("flavour", ["manual", "field"])
def test_the_sim_backend_answers_as_the_flavour_its_settings_name(flavour: str) -> None:
    """drivers.ptu.sim_flavour is a typed setting: the server, a --set and the consoles reach
    the field unit's replies without code; a misspelled flavour is refused with the choices."""
    from drivers.ptu.emulator import FLAVOURS

    dev = create({**FAST, "sim_flavour": flavour})
    try:
        lim = dev.limits()
        assert (lim["pan"]["min"], lim["pan"]["max"]) == FLAVOURS[flavour].limits["pan"]
        assert (lim["tilt"]["min"], lim["tilt"]["max"]) == FLAVOURS[flavour].limits["tilt"]
        assert dev.speed()[0] == min(1000, FLAVOURS[flavour].speed_bounds["pan"][1])  # speed 1000 fits the unit
        assert dev.status()["flavour"] == flavour
        assert dev.reset() == (0.0, 0.0)
    finally:
        dev.close()
    with pytest.raises(ValueError, match="manual"):
        create({**FAST, "sim_flavour": "fieldd"})
