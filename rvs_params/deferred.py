"""Modules imported where first used, not where named.

Importing scipy costs a process about 0.7 s of CPU (its compiled extensions and array-API
layer), which every CLI and server start paid whether or not anything it ran used scipy: a
``rvs-server --help``, a command line refused, a server that serves before its first job. A
module named through :func:`deferred` is imported the first time one of its attributes is
read, through the import system's own lock, so two job threads that reach it together get one
module (``importlib.util.LazyLoader`` gives no such promise)."""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["deferred"]


class _Deferred:
    __slots__ = ("_name",)

    def __init__(self, name: str) -> None:
        self._name = name

    def __getattr__(self, attr: str) -> Any:
        return getattr(importlib.import_module(self._name), attr)

    def __repr__(self) -> str:
        return f"<deferred module {self._name!r}>"


def deferred(name: str) -> Any:
    """``name`` (a dotted module path), imported when an attribute of it is first read."""
    return _Deferred(name)
