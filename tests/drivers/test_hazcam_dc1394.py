"""The FireWire hazcam backend: a clear E_DEVICE without libdc1394, the GUIDs it asks for, and a
pair's frames through the stereo pair's binding against its fake library."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import support.fake_dc1394 as fake

import drivers.hazcam as hazcam
from drivers.base import DeviceError
from drivers.hazcam.dc1394 import Dc1394Hazcams


def test_without_libdc1394_the_hazcams_fail_with_a_device_error_saying_what_to_install(tmp_path: Path) -> None:
    dev = hazcam.create({"backend": "dc1394", "cameras": "front", "library": str(tmp_path / "libdc1394.so.25")})
    with pytest.raises(DeviceError, match="libdc1394 not found") as err:
        dev.open()
    assert err.value.device == "hazcam"
    assert "drivers.hazcam.library" in err.value.message and "apt install libdc1394" in err.value.message
    assert not dev.status()["open"]
    off = hazcam.create({"backend": "dc1394", "library": str(tmp_path / "none.so")})
    off.open()  # off: the library is never asked for
    assert off.status()["open"] and off.cameras() == []


def test_the_pairs_are_found_by_their_configured_guids() -> None:
    a, b = f"{fake.GUID_A:016x}", f"{fake.GUID_B:016x}"
    settings = hazcam.BACKENDS.settings({"backend": "dc1394", "cameras": "front", "size": [64, 48]})
    with pytest.raises(DeviceError, match="set drivers.hazcam.front_left_id and front_right_id") as err:
        hazcam.Hazcam(settings, Dc1394Hazcams(settings, lib=fake.FakeLib())).open()
    assert a in err.value.message and b in err.value.message  # what the bus holds
    wrong = hazcam.BACKENDS.settings({**settings.as_dict(), "front_left_id": a, "front_right_id": "deadbeef"})
    with pytest.raises(DeviceError, match="00000000deadbeef not on the FireWire bus"):
        hazcam.Hazcam(wrong, Dc1394Hazcams(wrong, lib=fake.FakeLib())).open()

    good = hazcam.BACKENDS.settings({**settings.as_dict(), "front_left_id": a, "front_right_id": b})
    dev = hazcam.Hazcam(good, Dc1394Hazcams(good, lib=fake.FakeLib()))
    dev.open()
    left, right = dev.images("front")
    np.testing.assert_array_equal(left, fake.pattern(40, 64, 48, 1).reshape(48, 64))  # GUID_A's frames
    np.testing.assert_array_equal(right, fake.pattern(80, 64, 48, 1).reshape(48, 64))
    assert set(dev.check()["check"]["front"]) == {a, b}
    dev.close()
