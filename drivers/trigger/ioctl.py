"""ppdev ioctl request numbers, computed the way <linux/ppdev.h> and <asm-generic/ioctl.h> do.

Computing them (rather than pasting magic numbers) keeps the derivation reviewable; the test
pins them to the values the C headers give on x86-64 and arm64 (asm-generic layout).
"""

from __future__ import annotations

import ctypes

_IOC_NRBITS = 8
_IOC_TYPEBITS = 8
_IOC_SIZEBITS = 14
_IOC_NRSHIFT = 0
_IOC_TYPESHIFT = _IOC_NRSHIFT + _IOC_NRBITS
_IOC_SIZESHIFT = _IOC_TYPESHIFT + _IOC_TYPEBITS
_IOC_DIRSHIFT = _IOC_SIZESHIFT + _IOC_SIZEBITS
_IOC_NONE = 0
_IOC_WRITE = 1
_IOC_READ = 2


def _ioc(direction: int, type_: str, nr: int, size: int) -> int:
    return (
        (direction << _IOC_DIRSHIFT)
        | (ord(type_) << _IOC_TYPESHIFT)
        | (nr << _IOC_NRSHIFT)
        | (size << _IOC_SIZESHIFT)
    )


def _io(type_: str, nr: int) -> int:
    return _ioc(_IOC_NONE, type_, nr, 0)


def _iow(type_: str, nr: int, ctype: type) -> int:
    return _ioc(_IOC_WRITE, type_, nr, ctypes.sizeof(ctype))


def _ior(type_: str, nr: int, ctype: type) -> int:
    return _ioc(_IOC_READ, type_, nr, ctypes.sizeof(ctype))


PP_IOCTL = "p"
PPRDATA = _ior(PP_IOCTL, 0x85, ctypes.c_ubyte)
PPWDATA = _iow(PP_IOCTL, 0x86, ctypes.c_ubyte)
PPCLAIM = _io(PP_IOCTL, 0x8B)
PPRELEASE = _io(PP_IOCTL, 0x8C)
PPEXCL = _io(PP_IOCTL, 0x8F)
