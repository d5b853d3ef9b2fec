"""The long suite's marks: what only ``RVS_LONG=1`` runs, or runs longer (docs/RELIABILITY.md)."""

from __future__ import annotations

import os
from typing import Any

import pytest

LONG = os.environ.get("RVS_LONG", "") == "1"
long = pytest.mark.long  # RVS_LONG=1 runs this test longer (more examples, seeds, kill points, ...)


def long_suite(obj: Any) -> Any:
    """A test (or a ``pytest.param``'s marks) that runs only with RVS_LONG=1, where a shorter
    version of the same check runs always; CI's second pass (``-m long``) runs it."""
    skip = pytest.mark.skipif(not LONG, reason="long suite: run with RVS_LONG=1 (see docs/RELIABILITY.md)")
    return long(skip(obj))


def long_test(fn: Any) -> Any:
    """A whole test that runs only with RVS_LONG=1 (the long suite CI runs after the default one)."""
    for mark in long_only():
        fn = mark(fn)
    return fn


def long_only() -> list[Any]:
    """The marks of a ``pytest.param`` that runs only with RVS_LONG=1."""
    return [long, pytest.mark.skipif(not LONG, reason="long variant: run with RVS_LONG=1")]
