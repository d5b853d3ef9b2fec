"""A benchmark's rows, one per item, in processes where asked: each printed as JSON as it comes,
so a long run cut short keeps what it measured."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any


def streamed(fn: Callable[[Any], dict[str, Any]], todo: list[Any], jobs: int, show: bool = True
             ) -> list[dict[str, Any]]:
    """``fn`` of every item of ``todo``, in order, in ``jobs`` spawned processes (each builds its
    own scene and server: nothing of the parent's is shared); ``show`` False keeps rows too long
    to read (a look's every cell) off the output."""
    rows: list[dict[str, Any]] = []
    if jobs > 1:
        import multiprocessing

        with multiprocessing.get_context("spawn").Pool(jobs) as pool:
            for row in pool.imap(fn, todo):
                rows.append(row)
                if show:
                    print(json.dumps(row), flush=True)
    else:
        for item in todo:
            rows.append(fn(item))
            if show:
                print(json.dumps(rows[-1]), flush=True)
    return rows
