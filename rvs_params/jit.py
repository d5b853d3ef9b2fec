"""How the project compiles its numba kernels: once, on first use, releasing the GIL.

Importing numba costs about 0.3 s, so nothing here imports it until a kernel is compiled, and a
module whose import must stay cheap keeps its kernels behind a function or in a module of their
own that it imports on first use. Every kernel releases the GIL (``nogil``), so a job thread
inside one does not hold up the server's event loop. Kernels are cached on disk (``cache=True``:
compiled once per installation, then loaded); where no cache location is writable (a read-only
install), they are compiled in each process instead. Without numba a kernel is the plain Python
function, which computes the same result, only slower.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from typing import Any, TypeVar, overload

F = TypeVar("F", bound=Callable[..., Any])


def _find_numba() -> bool:
    try:
        return importlib.util.find_spec("numba") is not None
    except (ImportError, ValueError):
        return False


HAVE_NUMBA = _find_numba()  # asked without importing numba


@overload
def jit(fn: F, /, **options: Any) -> F: ...


@overload
def jit(fn: None = None, /, **options: Any) -> Callable[[F], F]: ...


def jit(fn: F | None = None, /, **options: Any) -> F | Callable[[F], F]:
    """``fn`` compiled by numba's ``njit`` (``nogil``, cached, with ``options`` such as
    ``error_model`` or ``inline``), or ``fn`` itself without numba. Also a decorator, bare or with
    options: ``@jit``, ``@jit(inline="always")``."""
    if fn is None:
        return lambda f: jit(f, **options)
    try:
        import numba
    except ImportError:  # pragma: no cover - numba is a core dependency; this is for broken installs
        return fn
    try:  # compiled once, then loaded from numba's cache (beside the source file or the user's)
        return numba.njit(cache=True, nogil=True, **options)(fn)
    except RuntimeError:  # no writable cache location: compile in each process instead
        return numba.njit(cache=False, nogil=True, **options)(fn)
