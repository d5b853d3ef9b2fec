"""The C heap under the server: glibc keeps what a thread freed in that thread's arena, so a
long-running server's resident size follows its past peaks unless it bounds the arenas and hands
freed pages back. A no-op where the C library is not glibc."""

from __future__ import annotations

import ctypes
import gc

M_ARENA_MAX = -8  # glibc's mallopt parameter


def bound_malloc_arenas(arenas: int) -> bool:
    """Let the threads allocate from at most ``arenas`` glibc arenas; False where the C library
    has no mallopt or refuses. Each arena keeps the memory its threads freed: with glibc's
    default of one a thread (up to 8 a core), a rover's server would grow by a render's worth
    each time a job ran on a thread that had not rendered yet, for as long as it runs. Arenas
    made before the call stay, and the bound holds for the whole process: the server program
    calls it before any thread starts, while a process that embeds a server (a test, a bench)
    keeps its own allocator."""
    if arenas <= 0:
        return False
    try:
        return bool(ctypes.CDLL(None).mallopt(M_ARENA_MAX, arenas))
    except (OSError, AttributeError):
        return False


def trim() -> None:
    """Return the arenas' free pages to the system. A job's renders free tens of megabytes that
    glibc would keep for the next one; the worker trims when a job ends, so the server at rest
    holds what it uses (about 35 MB less after the fuzz suite's mixed traffic). ctypes drops the
    GIL for the call, so the event loop runs on meanwhile."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass


def give_back_memory() -> None:
    """Return freed heap to the system after dropping a client with megabytes queued, so a rover's
    server does not carry every flood it survived. The collection first: a dropped connection's
    objects may sit in reference cycles, and their memory is only free (and trimmable) once they
    are collected."""
    gc.collect()
    trim()
