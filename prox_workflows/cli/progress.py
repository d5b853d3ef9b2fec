"""The console tools' progress bar."""

from __future__ import annotations

import sys


def show_progress(done: int, total: int, message: str, phase: str = "") -> None:
    """The console tools' progress bar on stderr: phase, bar, count, message, one line redrawn."""
    width = 30
    filled = int(width * done / max(total, 1))
    sys.stderr.write(f"\r{phase[:10]:<10} [{'#' * filled}{'.' * (width - filled)}] {done}/{total} "
                     f"{message[:40]:<40}")
    sys.stderr.flush()
