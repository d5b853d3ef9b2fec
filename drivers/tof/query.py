"""Which SR4000 cameras are on the USB bus, asked through pyusb (rvs-libtof's query function).

This works without libMesaSR, so an operator can find a camera's serial number before opening
it; it does need a libusb backend for pyusb.
"""

from __future__ import annotations

from typing import Any

from drivers.base import DeviceError

from .constants import SR4000_PRODUCT_IDS, SR4000_VENDOR_ID

NO_BACKEND_HELP = (
    "USB query needs a libusb backend for pyusb and none was found: install libusb-1.0 "
    "(Debian/Ubuntu: apt install libusb-1.0-0), or set PYUSB_DEBUG=debug to see what pyusb tried"
)


def find_cameras(backend: Any = None) -> list[dict[str, Any]]:
    """SR4000s (vendor 0x1ad2, product 0x0074/0x0075) on the bus, with their USB strings.

    Strings the process may not read (no udev permission) are None rather than an error.
    """
    import usb.core
    import usb.util

    try:
        devices = list(
            usb.core.find(
                find_all=True,
                backend=backend,
                idVendor=SR4000_VENDOR_ID,
                custom_match=lambda d: d.idProduct in SR4000_PRODUCT_IDS,
            )
        )
    except usb.core.NoBackendError:
        raise DeviceError("tof", NO_BACKEND_HELP) from None
    except usb.core.USBError as exc:
        raise DeviceError("tof", f"USB query failed: {exc}") from None
    found = []
    for dev in devices:
        found.append(
            {
                "vendor_id": f"0x{dev.idVendor:04x}",
                "product_id": f"0x{dev.idProduct:04x}",
                "bus": getattr(dev, "bus", None),
                "address": getattr(dev, "address", None),
                "serial": _string(dev, getattr(dev, "iSerialNumber", 0)),
                "manufacturer": _string(dev, getattr(dev, "iManufacturer", 0)),
                "product": _string(dev, getattr(dev, "iProduct", 0)),
            }
        )
    return found


def _string(dev: Any, index: int) -> str | None:
    if not index:
        return None
    import usb.util

    try:
        return usb.util.get_string(dev, index)
    except (ValueError, NotImplementedError, OSError):  # USBError is an OSError: permissions
        return None
