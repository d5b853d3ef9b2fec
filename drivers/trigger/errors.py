"""Turning an OSError from the parallel port into a DeviceError that says how to fix it.

The three failures people actually meet with a JR trigger box on Linux are a missing
``/dev/parportN`` (ppdev not loaded, no port), a permission problem (user not in ``lp``) and
a busy port (the ``lp`` printer module claimed it first). Each message names the fix.
"""

from __future__ import annotations

import errno

from drivers.base import DeviceError

DEVICE = "trigger"


def port_error(err: OSError, path: str, action: str) -> DeviceError:
    """Map ``err`` (raised while ``action`` on ``path``) to a DeviceError with the remedy."""
    code = err.errno
    if code == errno.ENOENT:
        hint = (
            f"no parallel port device {path}: load the ppdev module (`sudo modprobe ppdev`), check that "
            "the port exists (BIOS setting or PCIe card, `ls /dev/parport*`), or point "
            "drivers.trigger.device at the right /dev/parportN"
        )
    elif code in (errno.EACCES, errno.EPERM):
        hint = (
            f"permission denied on {path}: add the user to the lp group (`sudo usermod -aG lp $USER`, "
            'then log in again) or install a udev rule: KERNEL=="parport[0-9]*", GROUP="lp", MODE="0660"'
        )
    elif code == errno.EBUSY:
        hint = (
            f"{path} is busy: another driver holds the port, usually the printer module lp "
            "(`sudo rmmod lp`, and add `blacklist lp` to /etc/modprobe.d/ to keep it away), "
            "or another program has claimed it"
        )
    elif code in (errno.ENXIO, errno.ENODEV):
        hint = (
            f"{path} exists but no port answers behind it: load the port driver (`sudo modprobe parport_pc`) "
            "and check the port is enabled in the BIOS"
        )
    else:
        name = errno.errorcode.get(code or 0, "?")
        hint = f"{path}: {err.strerror or err} ({name})"
    return DeviceError(DEVICE, f"{action} failed: {hint}")
