"""What the see loop did in one navigate (:class:`LoopStats`): its counts and timings, reported in
navigate's OK line and read by the benchmarks (``tools.bench.navigate``, ``tools.bench.scale``)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..protocol import Fixed


@dataclass
class LoopStats:
    """What the see loop did in one navigate: reported in its OK line and read by the benchmark."""

    scans: int = 0
    replans: int = 0
    stops: int = 0
    looks: int = 0  # frames taken standing at unseen ground ahead (see_unseen)
    retreats: int = 0  # dead ends the chooser backed out of (sections.Chooser)
    cycles: int = 0
    cycle_ms: list[float] = field(default_factory=list)  # rolling map + hazard + check, wall ms
    # the same in the process's CPU ms: on a shared machine the wall time also counts the waits
    # for a core, which the cycle's own cost does not include (the rest of the process, status
    # replies included, counts in it: an upper bound)
    cycle_cpu_ms: list[float] = field(default_factory=list)
    frame_ms: list[float] = field(default_factory=list)  # the frames' captures (the simulator's renders), wall ms
    replan_ms: list[float] = field(default_factory=list)  # A* on the merged maps (the chooser: a choice), wall ms
    replan_cpu_ms: list[float] = field(default_factory=list)  # the same, process CPU ms

    def cycle(self, wall0: float, cpu0: float) -> None:
        """One cycle ended that started at ``wall0`` (monotonic) and ``cpu0`` (process time)."""
        self.cycles += 1
        self.cycle_ms.append((time.monotonic() - wall0) * 1000)
        self.cycle_cpu_ms.append((time.process_time() - cpu0) * 1000)

    def replanned(self, wall0: float, cpu0: float) -> None:
        """One plan (or choice) made that started at ``wall0`` (monotonic) and ``cpu0`` (process time)."""
        self.replan_ms.append((time.monotonic() - wall0) * 1000)
        self.replan_cpu_ms.append((time.process_time() - cpu0) * 1000)

    def fields(self) -> dict[str, Any]:
        """The OK line's keys."""
        def mean(v: list[float]) -> float:
            return float(np.mean(v)) if v else 0.0

        def p95(v: list[float]) -> float:
            return float(np.percentile(v, 95)) if v else 0.0

        return {"scans": self.scans, "replans": self.replans, "stops": self.stops, "looks": self.looks,
                "retreats": self.retreats, "cycles": self.cycles,
                "cycle_ms": Fixed(mean(self.cycle_ms), 1),
                "cycle_ms_max": Fixed(max(self.cycle_ms, default=0.0), 1),
                "cycle_ms_p95": Fixed(p95(self.cycle_ms), 1), "cycle_cpu_ms_p95": Fixed(p95(self.cycle_cpu_ms), 1),
                "frame_ms": Fixed(mean(self.frame_ms), 1), "replan_ms": Fixed(mean(self.replan_ms), 1),
                "replan_ms_p95": Fixed(p95(self.replan_ms), 1), "replan_cpu_ms_p95": Fixed(p95(self.replan_cpu_ms), 1)}

