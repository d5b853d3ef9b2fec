"""The job runner: one hardware-or-map job at a time, run off the event loop.

A job's handler runs in a worker thread so that status queries stay fast while it computes;
it reports through :meth:`Job.progress` and checks :meth:`Job.check` at view and step
boundaries; device waits watch ``Job.cancel`` themselves, which is how ``break`` stops it within
a fraction of a second. ``break`` does not wait for that: :meth:`Job.stop` tells it, under the
lock the worker thread decides the job's outcome with, whether the job will end interrupted, so
the break can answer at once and the job's own ERROR follows. The worker thread binds the job's
log context (connection, command, tag, job), so every line the handler logs, through whatever
library, says which request it belongs to, as the event loop's lines do.

The final lines of the last :data:`HISTORY` jobs are kept (:class:`JobRecord`): a client that lost
its connection while its job ran asks ``status -job N`` how it ended.
"""

from __future__ import annotations

import asyncio
import threading
import time
import traceback
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

import structlog

from drivers.base import DeviceError, DeviceInterrupted

from .bus import tapped_call
from .heap import trim
from .protocol import ProtocolError

if TYPE_CHECKING:
    from .app import App

log = structlog.get_logger("rvs.jobs")

HISTORY = 32  # finished jobs whose final line status -job can still tell


class Interrupted(Exception):
    """Raised inside a job when break or quit asked it to stop."""


@dataclass
class Job:
    id: int
    command: str
    module: str
    params: dict[str, Any]
    tag: str | None
    emit: Callable[[str, dict[str, Any]], None]  # (status, fields) -> line to the requester
    cancel: threading.Event = field(default_factory=threading.Event)
    started: float = field(default_factory=time.monotonic)
    done: int = 0
    total: int = 0
    message: str = ""
    phase: str = ""  # the phase the last PROGRESS line was about ("" for a job without phases)
    context: dict[str, Any] = field(default_factory=dict)  # e.g. {"leg": 2}: part of the phase's identity
    progress_dropped: int = 0  # lines a handler reported against the progress contract (a bug)
    uses_hardware: bool = False
    connection: int = 0  # id of the connection that started it (telnet's interrupt stops only its own)
    # Set when that connection closed: its lines go nowhere, and a wait for what it would have
    # sent (navigate's wait for the GNC's pose) may give up
    requester_gone: threading.Event = field(default_factory=threading.Event)
    finished: threading.Event = field(default_factory=threading.Event)
    succeeded: bool | None = None  # set when it finished: True if its final line is OK
    _reported: bool = False
    # Guards the moment the outcome is settled: stop() and the worker thread's decision take it,
    # so a stop either comes first (the job ends interrupted) or finds the outcome settled.
    _decide: threading.Lock = field(default_factory=threading.Lock, repr=False)
    _decided: bool = False
    _holds: int = 0  # breaks still answering: the final line waits for their replies (loop only)
    _held: Callable[[], None] | None = field(default=None, repr=False)  # the finish they hold back
    log_context: dict[str, Any] = field(default_factory=dict)  # bound in the worker thread's log lines
    # The server state a handler works on (devices, config, pose, maps, data directory).
    app: App = field(kw_only=True, repr=False)

    @property
    def cancelled(self) -> bool:
        return self.cancel.is_set()

    def stop(self) -> bool:
        """Ask the job to stop; True if it will end interrupted, False if its outcome (OK, or an
        error of its own) was settled before: then nothing was interrupted. Never waits."""
        with self._decide:
            self.cancel.set()
            return not self._decided

    def check(self) -> None:
        """Stop here if break or quit asked for it (call at every view and step boundary)."""
        if self.cancel.is_set():
            raise Interrupted(f"{self.command} job {self.id} was interrupted")

    def sleep(self, seconds: float) -> None:
        """Wait that long unless interrupted first."""
        if self.cancel.wait(seconds):
            self.check()

    def progress(self, done: int, total: int, message: str = "", *, phase: str = "", **context: Any) -> None:
        """Send a PROGRESS line that a progress bar can use.

        The contract (docs/PROTOCOL.md): within one phase (``phase`` plus ``context``, e.g. the
        leg of a navigate) ``total`` never changes and ``done`` only grows. A new phase starts
        its own count. A line that would break the contract is not sent; it is counted in
        ``progress_dropped`` so that the tests catch the handler that reported it.
        """
        new_phase = not self._reported or phase != self.phase or context != self.context
        if not new_phase and (total != self.total or done <= self.done):
            self.progress_dropped += 1
            log.warning("progress_dropped", job=self.id, phase=phase, done=done, total=total,
                        last_done=self.done, last_total=self.total)
            return
        self._reported = True
        self.done, self.total, self.message, self.phase, self.context = done, total, message, phase, context
        fields: dict[str, Any] = {"phase": phase} if phase else {}
        fields.update(context)
        fields.update(done=done, total=total, message=message)
        self.emit("PROGRESS", fields)


@dataclass(frozen=True)
class JobRecord:
    """How a finished job ended: its final line's status and fields (without ``job``)."""

    id: int
    command: str
    tag: str | None
    connection: int
    status: str  # OK or ERROR
    fields: dict[str, Any]
    seconds: float  # from its ACK to its final line


def _failed_device(exc: BaseException | None) -> bool:
    """A device failure stays E_DEVICE (fault mode) even when a break came at the same moment."""
    return isinstance(exc, TimeoutError) or (isinstance(exc, DeviceError) and not isinstance(exc, DeviceInterrupted))


def error_fields(exc: BaseException) -> tuple[dict[str, Any], bool]:
    """Map an exception from a handler to ERROR fields; the flag says whether a device failed."""
    if isinstance(exc, ProtocolError):
        return {"code": exc.code, "message": exc.message}, False
    if isinstance(exc, Interrupted):
        return {"code": "E_INTERRUPTED", "message": f"{exc}; its earlier outputs are kept"}, False
    if isinstance(exc, DeviceError):
        return {
            "code": "E_DEVICE",
            "device": exc.device,
            "message": f"{exc}; the server is in fault mode, send reset to recover",
        }, True
    if isinstance(exc, TimeoutError):
        return {"code": "E_DEVICE", "message": f"timeout: {exc}; send reset to recover"}, True
    if isinstance(exc, OSError):
        return {"code": "E_IO", "message": f"file system refused: {exc}; check the data directory"}, False
    if isinstance(exc, ValueError):
        return {"code": "E_ARG", "message": str(exc)}, False
    return {
        "code": "E_INTERNAL",
        "message": f"internal error ({type(exc).__name__}: {exc}); logged, the server keeps serving",
    }, False


class JobRunner:
    """Holds the single job slot and the worker thread it runs in."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self.loop = loop
        self.current: Job | None = None
        self.last: Job | None = None
        self.history: OrderedDict[int, JobRecord] = OrderedDict()  # the last HISTORY finished, oldest first
        self._next_id = 1
        self._pool = ThreadPoolExecutor(max_workers=2, thread_name_prefix="rvs-job")

    @property
    def issued(self) -> int:
        """The newest job id given out (0 before the first)."""
        return self._next_id - 1

    def new_id(self) -> int:
        n = self._next_id
        self._next_id += 1
        return n

    def start(
        self,
        job: Job,
        work: Callable[[Job], dict[str, Any]],
        on_done: Callable[[Job, dict[str, Any] | None, BaseException | None], None],
    ) -> None:
        """Run ``work(job)`` in the worker thread; ``on_done`` runs on the event loop."""
        assert self.current is None
        self.current = job

        def run() -> None:
            result: dict[str, Any] | None = None
            error: BaseException | None = None
            with structlog.contextvars.bound_contextvars(**job.log_context):
                try:
                    result = work(job)
                except BaseException as exc:  # noqa: BLE001 - every failure becomes an ERROR line
                    error = exc
                    if not isinstance(exc, ProtocolError | Interrupted | DeviceError | OSError | ValueError):
                        log.error("job_failed", job=job.id, command=job.command, trace=traceback.format_exc())
                with job._decide:
                    job._decided = True
                    # A stop that came before this point was told the job ends interrupted: so it
                    # does, whatever the handler made of the stop (a result, a driver's own error).
                    if job.cancel.is_set() and not isinstance(error, Interrupted) and not _failed_device(error):
                        if error is not None:
                            log.info("job_error_after_stop", job=job.id, error=repr(error))
                        result, error = None, Interrupted(f"{job.command} job {job.id} was interrupted")
            self.loop.call_soon_threadsafe(self._finish, job, result, error, on_done)
            del result, error
            trim()  # after the final line is on its way; the work's arrays are freed by now

        self._pool.submit(run)

    def _finish(
        self,
        job: Job,
        result: dict[str, Any] | None,
        error: BaseException | None,
        on_done: Callable[[Job, dict[str, Any] | None, BaseException | None], None],
    ) -> None:
        if job._holds:  # a break that caught it has not answered yet: its OK goes first
            job._held = lambda: self._finish(job, result, error, on_done)
            return
        if self.current is job:
            self.current = None
        self.last = job
        job.succeeded = error is None
        status, fields = ("OK", dict(result or {})) if error is None else ("ERROR", error_fields(error)[0])
        self.history[job.id] = JobRecord(job.id, job.command, job.tag, job.connection, status, fields,
                                         time.monotonic() - job.started)
        while len(self.history) > HISTORY:
            self.history.popitem(last=False)
        job.finished.set()
        on_done(job, result, error)

    def hold_final(self, job: Job) -> None:
        """Keep ``job``'s final line back until :meth:`release_final` (loop only): a break answers
        before the ERROR of the job it stopped, however fast the job stops."""
        job._holds += 1

    def release_final(self, job: Job) -> None:
        job._holds -= 1
        if job._holds == 0 and job._held is not None:
            held, job._held = job._held, None
            held()

    def record(self, job_id: int) -> JobRecord | None:
        """How job ``job_id`` ended, if it is among the last HISTORY finished."""
        return self.history.get(job_id)

    async def interrupt(self, job: Job | None = None, timeout: float = 1.5) -> Job | None:
        """Ask ``job`` (default: the running one) to stop and wait, without blocking the loop,
        until it has (server shutdown: the job's ERROR goes out before the connections close)."""
        job = job or self.current
        if job is None:
            return None
        job.stop()
        deadline = time.monotonic() + timeout
        while not job.finished.is_set() and time.monotonic() < deadline:
            await asyncio.sleep(0.01)
        return job

    def shutdown(self) -> None:
        if self.current is not None:
            self.current.stop()
        self._pool.shutdown(wait=False, cancel_futures=True)


def device_call(job: Job, fn: Any, *args: Any, **kwargs: Any) -> Any:
    """Call a driver with the job's cancel event; a stop caused by break is E_INTERRUPTED, not a fault."""
    try:
        return tapped_call(job.app.bus, fn, *args, cancel=job.cancel, **kwargs)
    except Exception:
        if job.cancelled:
            raise Interrupted(f"{job.command} job {job.id} was interrupted") from None
        raise


def default_stem(prefix: str) -> str:
    """A job's product name when the request gives none: the kind and the UTC time to the ms."""
    return f"{prefix}_{datetime.now(UTC).strftime('%Y%m%dT%H%M%S_%f')[:-3]}"
