"""Logging: structlog, JSON lines to the log file and readable lines on the console.

Context (connection, peer, command, tag, job) is bound once on a logger and carried by every
line, as structlog intends, rather than repeated in each call. On the event loop it is bound on
the connection's logger; a job's worker thread and a monitor's thread bind it in structlog's
contextvars (``rvs_server.jobs``, ``rvs_server.monitors``), so the lines that code logs, which
knows nothing of requests (the device registry, a driver), carry it too. The log file also says
which thread wrote each line, which is how a reader (and a test) tells a job's lines from the
event loop's.
"""

from __future__ import annotations

import logging
import sys
import threading
from pathlib import Path
from typing import Any

import structlog


def add_thread(logger: Any, method: str, event_dict: dict[str, Any]) -> dict[str, Any]:
    """The writing thread's name (rvs-job_0, rvs-hazard, the loop's): run by the file handler's
    formatter, which formats in the thread that logged."""
    event_dict.setdefault("thread", threading.current_thread().name)
    return event_dict


def setup(level: str = "info", log_file: Path | None = None, console: bool = True) -> None:
    shared = [
        structlog.contextvars.merge_contextvars,
        structlog.stdlib.add_log_level,
        structlog.stdlib.add_logger_name,
        structlog.processors.TimeStamper(fmt="iso", utc=True),
    ]
    structlog.configure(
        processors=[structlog.stdlib.filter_by_level, *shared,
                    structlog.stdlib.ProcessorFormatter.wrap_for_formatter],
        logger_factory=structlog.stdlib.LoggerFactory(),
        wrapper_class=structlog.stdlib.BoundLogger,
        cache_logger_on_first_use=True,
    )
    root = logging.getLogger()
    for handler in list(root.handlers):
        root.removeHandler(handler)
        handler.close()
    root.setLevel(getattr(logging, level.upper(), logging.INFO))
    if console:
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(structlog.stdlib.ProcessorFormatter(
            processors=[structlog.stdlib.ProcessorFormatter.remove_processors_meta,
                        structlog.dev.ConsoleRenderer(colors=False)],
            foreign_pre_chain=shared,
        ))
        root.addHandler(handler)
    if not console and log_file is None:
        root.addHandler(logging.NullHandler())
    if log_file is not None:
        log_file.parent.mkdir(parents=True, exist_ok=True)
        fh = logging.FileHandler(log_file, encoding="utf-8")
        fh.setFormatter(structlog.stdlib.ProcessorFormatter(
            processors=[structlog.stdlib.ProcessorFormatter.remove_processors_meta,
                        add_thread,
                        structlog.processors.format_exc_info,
                        structlog.processors.JSONRenderer()],
            foreign_pre_chain=shared,
        ))
        root.addHandler(fh)
