"""Finding SR4000s on the USB bus through pyusb, without libMesaSR."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import usb.core
import usb.util

from drivers.base import DeviceError
from drivers.tof import query


def _device(vid, pid, serial_index=3):
    return SimpleNamespace(idVendor=vid, idProduct=pid, bus=1, address=7, iSerialNumber=serial_index, iManufacturer=1, iProduct=2)


def test_query_filters_sr4000_ids_and_reads_strings(monkeypatch):
    devices = [_device(0x1AD2, 0x0074), _device(0x1AD2, 0x0075, serial_index=0), _device(0x1AD2, 0x0099), _device(0x046D, 0x0074)]
    seen = {}

    def fake_find(find_all, backend, idVendor, custom_match):  # noqa: N803 - pyusb's keyword
        seen["vendor"] = idVendor
        return (d for d in devices if d.idVendor == idVendor and custom_match(d))

    strings = {1: "MESA Imaging", 2: "SR4000", 3: "4000002F"}

    def fake_string(dev, index):
        if dev.idProduct == 0x0075 and index == 1:
            raise usb.core.USBError("Access denied (insufficient permissions)")
        return strings[index]

    monkeypatch.setattr(usb.core, "find", fake_find)
    monkeypatch.setattr(usb.util, "get_string", fake_string)
    found = query.find_cameras()
    assert seen["vendor"] == 0x1AD2
    assert [(c["vendor_id"], c["product_id"]) for c in found] == [("0x1ad2", "0x0074"), ("0x1ad2", "0x0075")]
    assert found[0] == {
        "vendor_id": "0x1ad2",
        "product_id": "0x0074",
        "bus": 1,
        "address": 7,
        "serial": "4000002F",
        "manufacturer": "MESA Imaging",
        "product": "SR4000",
    }
    # No serial string index, and a string the process may not read: None, not an error.
    assert found[1]["serial"] is None and found[1]["manufacturer"] is None and found[1]["product"] == "SR4000"


def test_query_without_a_libusb_backend_says_so(monkeypatch):
    def no_backend(**kwargs):
        raise usb.core.NoBackendError("No backend available")

    monkeypatch.setattr(usb.core, "find", no_backend)
    with pytest.raises(DeviceError) as err:
        query.find_cameras()
    assert err.value.device == "tof"
    assert "libusb" in str(err.value) and "apt install libusb-1.0-0" in str(err.value)
