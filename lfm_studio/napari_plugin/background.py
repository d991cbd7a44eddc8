"""The plugin's one way to run engine work off the GUI thread: one job of the shared :class:`JobRunner`.

:class:`BackgroundTask` runs ``func(progress, cancel)`` (an engine-style callable: it
reports with ``progress(done, total, message)`` and stops at the engine's next
checkpoint once the ``threading.Event`` ``cancel`` is set) as a job of
:class:`lfm_studio.widgets.jobs.JobRunner`, the worker mechanism the studio uses too.
Progress reaches the GUI thread through a queued Qt signal; the end arrives as one
:class:`Outcome` (``"done"``, ``"cancelled"`` or ``"failed"`` with the error's text), so
callers add a layer only for ``"done"`` and a cancelled or failed task never leaves a half
result. Tensors in the result must be detached and on the CPU.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from qtpy.QtCore import QObject, Signal

from lfm_studio.engine.errors import error_text
from lfm_studio.engine.progress import ProgressCallback
from lfm_studio.widgets.jobs import JobContext, JobOutcome, JobRunner

_log = logging.getLogger(__name__)

TaskFunction = Callable[[ProgressCallback, threading.Event], Any]
_JOB = "task"


@dataclass(frozen=True)
class Outcome:
    """How a task ended: ``state`` is ``"done"`` (with ``value``), ``"cancelled"`` or ``"failed"`` (``message``)."""

    state: str
    value: Any = None
    message: str = ""
    details: str = ""
    seconds: float = 0.0


def _message(error: BaseException | None) -> str:
    """A failure for a notification: the text of a ValueError/OSError (ours name the fix; a refused
    design without pydantic's wrapping, :func:`~lfm_studio.engine.errors.error_text`), else with its type."""
    if isinstance(error, (ValueError, OSError)):
        return error_text(error)
    return f"{type(error).__name__}: {error}"


class BackgroundTask(QObject):
    """One background computation; create it on the GUI thread, connect, then :meth:`start`.

    Signals
    -------
    progressed(int, int, str) : ``(done, total, message)`` on the GUI thread.
    ended(Outcome) : once, on the GUI thread.
    """

    progressed = Signal(int, int, str)
    ended = Signal(object)

    def __init__(self, func: TaskFunction, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._func = func
        self._runner = JobRunner(self)
        self._runner.progressed.connect(self._on_progress)
        self._runner.ended.connect(self._on_ended)
        self._ctx: JobContext | None = None
        self._cancel_early = False
        self._started = False
        self.running = False
        self.outcome: Outcome | None = None
        if parent is not None:  # the owner going away stops the work at the next checkpoint
            runner = self._runner
            parent.destroyed.connect(lambda *_: runner.cancel())

    def start(self) -> None:
        """Start the worker thread (once)."""
        if self._started:
            raise RuntimeError("a BackgroundTask runs once; create a new one")
        self._started = True
        self.running = True
        self._runner.submit(_JOB, self._body)

    def _body(self, ctx: JobContext) -> Any:
        """Worker thread: the task with the job's progress and cancel token."""
        if self._cancel_early:
            ctx.cancel.set()
            ctx.check("cancelled before it started")
        return self._func(ctx.progress, ctx.cancel)

    def cancel(self) -> None:
        """Ask the task to stop at the engine's next checkpoint (between iterations, depths, lenslets)."""
        self._cancel_early = True
        self._runner.cancel(_JOB)

    @property
    def cancel_requested(self) -> bool:
        return self._cancel_early

    def _on_progress(self, name: str, generation: int, done: int, total: int, message: str) -> None:
        self.progressed.emit(done, total, message)

    def _on_ended(self, outcome: JobOutcome) -> None:
        self.running = False
        if outcome.state == "failed":
            _log.debug("background task failed:\n%s", outcome.details)
        self.outcome = Outcome(
            outcome.state,
            value=outcome.value,
            message=_message(outcome.error) if outcome.state == "failed" else "",
            details=outcome.details,
            seconds=outcome.seconds,
        )
        self.ended.emit(self.outcome)
