"""The ppdev trigger backend against a fake port: ioctl sequence, line reset, errno messages."""

from __future__ import annotations

import errno

import pytest

from drivers.base import DeviceError
from drivers.trigger import BACKENDS, Trigger, create, ioctl, ppdev

FAKE_FD = 42


class FakePort:
    """Records every ioctl on the fake fd; can make chosen requests fail."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, bytes | None]] = []
        self.fail: dict[int, OSError] = {}
        self.closed = False
        self.names = {
            ioctl.PPCLAIM: "CLAIM",
            ioctl.PPRELEASE: "RELEASE",
            ioctl.PPWDATA: "WDATA",
            ioctl.PPEXCL: "EXCL",
        }

    def ioctl(self, fd: int, request: int, arg: bytes | None = None) -> int:
        assert fd == FAKE_FD
        self.calls.append((self.names[request], arg))
        if request in self.fail:
            raise self.fail[request]
        return 0


@pytest.fixture()
def port(monkeypatch: pytest.MonkeyPatch) -> FakePort:
    fake = FakePort()
    opened: list[tuple[str, int]] = []

    def fake_open(path: str, flags: int) -> int:
        opened.append((path, flags))
        return FAKE_FD

    def fake_close(fd: int) -> None:
        assert fd == FAKE_FD
        fake.closed = True

    monkeypatch.setattr(ppdev.os, "open", fake_open)
    monkeypatch.setattr(ppdev.os, "close", fake_close)
    monkeypatch.setattr(ppdev.fcntl, "ioctl", fake.ioctl)
    fake.opened = opened  # type: ignore[attr-defined]
    return fake


def make(**extra: object) -> Trigger:
    dev = create({"backend": "ppdev", "device": "/dev/parport3", "pulse_us": 250, **extra})
    assert isinstance(dev.port, ppdev.PpdevTrigger)
    return dev


def test_ioctl_numbers_match_linux_ppdev_h() -> None:
    # Values printed by a C program including <linux/ppdev.h> on x86-64.
    assert ioctl.PPCLAIM == 0x708B
    assert ioctl.PPRELEASE == 0x708C
    assert ioctl.PPEXCL == 0x708F
    assert ioctl.PPWDATA == 0x40017086
    assert ioctl.PPRDATA == 0x80017085


def test_open_claims_exclusively_and_leaves_line_low(port: FakePort) -> None:
    dev = make()
    dev.open()
    assert port.opened == [("/dev/parport3", ppdev.os.O_RDWR)]  # type: ignore[attr-defined]
    assert port.calls == [("EXCL", None), ("CLAIM", None), ("WDATA", b"\x00"), ("RELEASE", None)]
    dev.close()
    assert port.closed


def test_pulse_sequence_width_and_count(port: FakePort, monkeypatch: pytest.MonkeyPatch) -> None:
    sleeps: list[float] = []
    monkeypatch.setattr(ppdev.time, "sleep", sleeps.append)
    dev = make()
    dev.open()
    port.calls.clear()
    assert dev.pulse() == 1
    assert port.calls == [("CLAIM", None), ("WDATA", b"\x01"), ("WDATA", b"\x00"), ("RELEASE", None)]
    assert sleeps == [pytest.approx(250e-6)]
    assert dev.pulse() == 2
    assert dev.status()["pulses"] == 2
    assert dev.status()["device"] == "/dev/parport3"


def test_line_reset_and_port_released_when_sleep_is_interrupted(
    port: FakePort, monkeypatch: pytest.MonkeyPatch
) -> None:
    def interrupted(_: float) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(ppdev.time, "sleep", interrupted)
    dev = make()
    dev.open()
    port.calls.clear()
    with pytest.raises(KeyboardInterrupt):
        dev.pulse()
    assert port.calls[-2:] == [("WDATA", b"\x00"), ("RELEASE", None)]
    assert dev.count == 0
    assert dev.status()["busy"] is False


def test_line_reset_when_raising_the_pin_fails(port: FakePort, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ppdev.time, "sleep", lambda _: None)
    dev = make()
    dev.open()
    port.calls.clear()
    writes: list[bytes | None] = []
    original = port.ioctl

    def flaky(fd: int, request: int, arg: bytes | None = None) -> int:
        if request == ioctl.PPWDATA:
            writes.append(arg)
            if arg == b"\x01":
                port.calls.append(("WDATA", arg))
                raise OSError(errno.EIO, "I/O error")
        return original(fd, request, arg)

    monkeypatch.setattr(ppdev.fcntl, "ioctl", flaky)
    with pytest.raises(DeviceError) as info:
        dev.pulse()
    assert info.value.device == "trigger"
    assert "raising pin 2" in info.value.message
    assert writes == [b"\x01", b"\x00"]
    assert port.calls[-1] == ("RELEASE", None)
    assert dev.status()["last_error"] == info.value.message


@pytest.mark.parametrize(
    ("code", "needle"),
    [
        (errno.ENOENT, "modprobe ppdev"),
        (errno.EACCES, "lp group"),
        (errno.EPERM, "udev rule"),
        (errno.EBUSY, "rmmod lp"),
        (errno.ENODEV, "parport_pc"),
    ],
)
def test_open_errno_becomes_device_error_with_fix(
    monkeypatch: pytest.MonkeyPatch, code: int, needle: str
) -> None:
    def failing_open(path: str, flags: int) -> int:
        raise OSError(code, "fail", path)

    monkeypatch.setattr(ppdev.os, "open", failing_open)
    dev = make()
    with pytest.raises(DeviceError) as info:
        dev.open()
    assert info.value.device == "trigger"
    assert needle in info.value.message
    assert "/dev/parport3" in info.value.message
    assert dev.status()["open"] is False


def test_busy_claim_at_open_is_reported_and_fd_closed(port: FakePort) -> None:
    port.fail[ioctl.PPCLAIM] = OSError(errno.EBUSY, "Device or resource busy")
    dev = make()
    with pytest.raises(DeviceError) as info:
        dev.open()
    assert "busy" in info.value.message and "rmmod lp" in info.value.message
    assert port.closed


def test_shared_mode_skips_ppexcl(port: FakePort) -> None:
    dev = make(exclusive=False)
    dev.open()
    assert ("EXCL", None) not in port.calls


def test_pulse_before_open_is_a_device_error() -> None:
    dev = make()
    with pytest.raises(DeviceError, match="not open"):
        dev.pulse()


def test_real_missing_port_names_the_fix() -> None:
    dev = create({"backend": "ppdev", "device": "/dev/parport-rvs-test-absent", "pulse_us": 100})
    with pytest.raises(DeviceError) as info:
        dev.open()
    assert info.value.device == "trigger"
    assert "no parallel port device /dev/parport-rvs-test-absent" in info.value.message


def test_invalid_width_and_backend_are_usage_errors() -> None:
    with pytest.raises(ValueError, match="pulse_us"):
        create({"backend": "ppdev", "pulse_us": 0})
    with pytest.raises(ValueError, match="unknown backend 'usb'.*registered: " + ", ".join(BACKENDS.names())):
        create({"backend": "usb"})
