"""The one worker mechanism of both Qt front ends: named background jobs on superqt workers (qtpy).

The studio runs its stages with :class:`JobRunner`; the napari plugin's
:class:`~lfm_studio.napari_plugin.background.BackgroundTask` is one job of a runner.

A job is a plain function ``func(ctx, *args) -> result`` run on a thread of the Qt
thread pool (:func:`superqt.utils.create_worker`). It reports with
``ctx.progress(done, total, message)`` (an engine progress callback), may hand over
intermediate results with ``ctx.partial(value)`` (a quick preview, an iterate), and
stops at the engine's next checkpoint once ``ctx.cancel`` (a ``threading.Event``, the
engine's cancel token) is set.

Each job has a name ("psf", "image", ...). Submitting a job under a name that is
still running cancels the old one and bumps the name's generation counter; whatever
a superseded job delivers later (result or partial) is dropped, so a late result from
old parameters never overwrites a newer one. Callbacks run on the GUI thread and only
for a job that succeeded and is still current: a failed or cancelled job leaves the
previous result untouched. A result callback that raises makes the job "failed" with that
error (never "done"); the exception also goes to ``sys.excepthook``, as any exception
escaping a slot does.
"""

from __future__ import annotations

import sys
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from qtpy.QtCore import QObject, QThreadPool, Signal
from superqt.utils import create_worker

from lfm_studio.engine.errors import error_text
from lfm_studio.engine.progress import CancelledError
from lfm_studio.widgets.job_status import JobStatus
from lfm_studio.widgets.numeric_text import shown_units_in


class JobContext:
    """What a running job gets: its name, generation, cancel token and reporting hooks."""

    def __init__(self, name: str, generation: int, relay: _Relay) -> None:
        self.name = name
        self.generation = generation
        self.cancel = threading.Event()
        self._relay = relay

    def progress(self, done: int, total: int, message: str = "") -> None:
        """Report progress (thread safe; the signature of an engine progress callback)."""
        self._relay.progress.emit(self.name, self.generation, int(done), int(total), str(message))

    def partial(self, value: Any) -> None:
        """Hand an intermediate result to the GUI thread (dropped if the job was superseded)."""
        self._relay.partial.emit(self.name, self.generation, value)

    def check(self, message: str = "cancelled") -> None:
        """Raise :class:`CancelledError` if cancellation was requested."""
        if self.cancel.is_set():
            raise CancelledError(message)


@dataclass(frozen=True)
class JobOutcome:
    """How a job ended: ``state`` is "done", "failed" or "cancelled"."""

    name: str
    generation: int
    state: str
    value: Any = None
    error: BaseException | None = None
    details: str = ""
    seconds: float = 0.0


@dataclass
class _Job:
    ctx: JobContext
    worker: Any
    on_result: Callable[[Any], None] | None
    on_partial: Callable[[Any], None] | None
    on_error: Callable[[JobOutcome], None] | None
    status: JobStatus


def _run(func: Callable[..., Any], ctx: JobContext, args: tuple) -> JobOutcome:
    """Worker-thread body: never raises, so every ending reaches the GUI thread as one outcome."""
    start = time.perf_counter()
    try:
        ctx.check()
        value = func(ctx, *args)
    except CancelledError:
        return JobOutcome(ctx.name, ctx.generation, "cancelled", seconds=time.perf_counter() - start)
    except Exception as error:
        return JobOutcome(
            ctx.name, ctx.generation, "failed", error=error, details=traceback.format_exc(),
            seconds=time.perf_counter() - start,
        )  # fmt: skip
    return JobOutcome(ctx.name, ctx.generation, "done", value=value, seconds=time.perf_counter() - start)


def _root_cause(error: BaseException) -> BaseException:
    """The original error behind wrappers such as psygnal's ``EmitLoopError`` (``raise ... from``)."""
    while error.__cause__ is not None:
        error = error.__cause__
    return error


def _one_line(error: BaseException | None) -> str:
    """``error`` for the status bar: its first non-empty line (the type name when it has no message; a
    refused design's own text, not pydantic's "1 validation error for ..." header), micrometres as
    the studio writes them ("µm", where the engine's message says "um")."""
    message = str(error) if error is None else shown_units_in(error_text(error))
    lines = [line.strip() for line in message.splitlines() if line.strip()]
    text = lines[0] if lines else ""
    return (
        f"{type(error).__name__}: {text}" if isinstance(error, (KeyError, IndexError)) or not text else text
    )


class _Relay(QObject):
    """Carries progress and partial results from worker threads to the GUI thread (queued)."""

    progress = Signal(str, int, int, int, str)
    partial = Signal(str, int, object)


class JobRunner(QObject):
    """Runs named jobs in the background; at most one current job per name.

    Signals
    -------
    status_changed(JobStatus) : a job started, progressed or ended.
    result_dropped(str, int) : a superseded job of that name and generation delivered late.
    progressed(str, int, int, int, str) : ``(name, generation, done, total, message)`` of a current job.
    ended(JobOutcome) : a current job ended ("done", "failed" or "cancelled"), after its callbacks.
    """

    status_changed = Signal(object)
    result_dropped = Signal(str, int)
    progressed = Signal(str, int, int, int, str)
    ended = Signal(object)

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._relay = _Relay(self)
        self._relay.progress.connect(self._on_progress)
        self._relay.partial.connect(self._on_partial)
        self._generations: dict[str, int] = {}
        self._jobs: dict[tuple[str, int], _Job] = {}
        self.dropped = 0  # late deliveries from superseded jobs (results and partials)

    # ----- submitting and cancelling -----

    def submit(
        self,
        name: str,
        func: Callable[..., Any],
        *args: Any,
        on_result: Callable[[Any], None] | None = None,
        on_partial: Callable[[Any], None] | None = None,
        on_error: Callable[[JobOutcome], None] | None = None,
    ) -> int:
        """Start ``func(ctx, *args)`` as job ``name``; supersede (cancel) a running one. Returns its generation."""
        for (job_name, _), job in self._jobs.items():
            if job_name == name:
                job.ctx.cancel.set()
        generation = self._generations.get(name, 0) + 1
        self._generations[name] = generation
        ctx = JobContext(name, generation, self._relay)
        worker = create_worker(_run, func, ctx, args, _start_thread=False, _ignore_errors=True)
        worker.returned.connect(self._on_returned)
        job = _Job(ctx, worker, on_result, on_partial, on_error, JobStatus(name, generation=generation))
        self._jobs[(name, generation)] = job
        self._set_status(job, JobStatus(name, "running", 0, 0, "starting", generation))
        worker.start()
        return generation

    def cancel(self, name: str | None = None) -> None:
        """Ask the current job ``name`` (default: every job) to stop at its next checkpoint."""
        for (job_name, generation), job in list(self._jobs.items()):
            if name not in (None, job_name):
                continue
            job.ctx.cancel.set()
            if generation == self._generations.get(job_name):
                self._set_status(job, replace(job.status, state="cancelling", message="cancelling"))

    def generation(self, name: str) -> int:
        """The generation of the latest job ``name`` (0: never submitted)."""
        return self._generations.get(name, 0)

    def is_running(self, name: str | None = None) -> bool:
        """Whether a current (not superseded) job ``name`` (default: any) is still running."""
        return any(gen == self._generations.get(n) and name in (None, n) for (n, gen) in self._jobs)

    def running_names(self) -> list[str]:
        return sorted({n for (n, gen) in self._jobs if gen == self._generations.get(n)})

    def shutdown(self, timeout_ms: int = 10_000) -> bool:
        """Cancel every job and wait for the threads; True when all ended in time."""
        for job in self._jobs.values():
            job.ctx.cancel.set()
        done = QThreadPool.globalInstance().waitForDone(timeout_ms)
        self._jobs.clear()
        return bool(done)

    # ----- deliveries (GUI thread) -----

    def _current(self, name: str, generation: int) -> _Job | None:
        job = self._jobs.get((name, generation))
        if job is None or generation != self._generations.get(name):
            return None
        return job

    def _on_progress(self, name: str, generation: int, done: int, total: int, message: str) -> None:
        job = self._current(name, generation)
        if job is not None and job.status.state == "running":
            self._set_status(job, JobStatus(name, "running", done, total, message, generation))
            self.progressed.emit(name, generation, done, total, message)

    def _on_partial(self, name: str, generation: int, value: Any) -> None:
        job = self._current(name, generation)
        if job is None or job.ctx.cancel.is_set():
            self.dropped += 1
            self.result_dropped.emit(name, generation)
            return
        if job.on_partial is not None:
            job.on_partial(value)

    def _on_returned(self, outcome: JobOutcome) -> None:
        key = (outcome.name, outcome.generation)
        job = self._jobs.pop(key, None)
        if job is None:
            return
        if outcome.generation != self._generations.get(outcome.name):
            if outcome.state == "done":
                self.dropped += 1
                self.result_dropped.emit(*key)
            return
        if outcome.state == "done" and job.ctx.cancel.is_set():
            outcome = JobOutcome(outcome.name, outcome.generation, "cancelled", seconds=outcome.seconds)
        if outcome.state == "done" and job.on_result is not None:
            try:
                job.on_result(outcome.value)
            except Exception as error:  # a result the GUI could not take: the stage failed
                outcome = JobOutcome(
                    outcome.name, outcome.generation, "failed", error=_root_cause(error),
                    details=traceback.format_exc(), seconds=outcome.seconds,
                )  # fmt: skip
                sys.excepthook(*sys.exc_info())  # reported like any exception escaping a slot
        if outcome.state == "done":
            message = f"done in {outcome.seconds:.1f} s"
            self._set_status(job, JobStatus(outcome.name, "done", 1, 1, message, outcome.generation))
        elif outcome.state == "cancelled":
            done, total = job.status.done, job.status.total
            self._set_status(
                job, JobStatus(outcome.name, "cancelled", done, total, "cancelled", outcome.generation)
            )
        else:
            message = f"failed: {_one_line(outcome.error)}"
            self._set_status(job, JobStatus(outcome.name, "failed", 0, 0, message, outcome.generation))
            if job.on_error is not None:
                job.on_error(outcome)
        self.ended.emit(outcome)

    def _set_status(self, job: _Job, status: JobStatus) -> None:
        job.status = status
        self.status_changed.emit(status)
