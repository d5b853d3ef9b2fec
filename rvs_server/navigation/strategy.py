"""What a mission asks of its strategy (``navigate -loop scan|see``): the mission scans 360
degrees, checks arrival and keeps the products; the strategy decides how each leg is planned and
driven between scans."""

from __future__ import annotations

from typing import Any, Protocol


class Strategy(Protocol):
    max_plans: int  # the mission's legs (scans and replans) end after this many

    def arrived(self, left: float) -> bool:
        """Whether the goal, ``left`` metres away and within the tolerance, is reached (a pose
        on dead reckoning may want a fix first)."""

    def drive_on(self, leg: int) -> bool:
        """Plan and drive leg ``leg`` without a scan; False: the mission scans first."""

    def scanned(self, leg: int, local: Any) -> None:
        """A 360-degree scan made the maps ``local`` (NavMaps of the scans so far) for leg ``leg``."""

    def leave(self) -> None:
        """The mission ended (reached, stopped, broken): what the strategy keeps for the next."""

    def fields(self) -> dict[str, Any]:
        """The strategy's keys of navigate's OK line."""
