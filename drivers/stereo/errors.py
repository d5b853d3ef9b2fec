"""Exceptions the camera backends raise for the front end to name the camera by side.

Backends know cameras by GUID; only the front end knows which one is "left" today (the ids can
be swapped), so backends raise these and the front end turns them into DeviceError messages.
"""

from __future__ import annotations

import threading


class GrabCancelled(Exception):
    """A grab was interrupted through its ``cancel`` argument (the server's ``break``)."""


class MissedTrigger(Exception):
    def __init__(self, guids: list[str], timeout: float, after: int | None = None) -> None:
        super().__init__(f"cameras {guids} missed their trigger")
        self.guids = list(guids)
        self.timeout = timeout
        self.after = after


class CameraLost(Exception):
    def __init__(self, guid: str, detail: str = "") -> None:
        super().__init__(f"camera {guid} lost {detail}")
        self.guid = guid
        self.detail = detail


def is_cancelled(cancel: object) -> bool:
    """``cancel`` may be None, a threading.Event or a callable returning a bool."""
    if cancel is None:
        return False
    if isinstance(cancel, threading.Event):
        return cancel.is_set()
    if callable(cancel):
        return bool(cancel())
    return bool(cancel)
