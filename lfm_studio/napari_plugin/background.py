"""The plugin's one way to run engine work off the GUI thread: a napari ``thread_worker`` with progress and cancel.

:class:`BackgroundTask` runs ``func(progress, cancel)`` (an engine-style callable: it
reports with ``progress(done, total, message)`` and stops at the engine's next
checkpoint once the ``threading.Event`` ``cancel`` is set) on a
:func:`napari.qt.threading.create_worker` thread. Progress reaches the GUI thread through
a queued Qt signal; the end arrives as one :class:`Outcome` (``"done"``, ``"cancelled"`` or
``"failed"`` with the error's text), so callers add a layer only for ``"done"`` and a
cancelled or failed task never leaves a half result. Tensors in the result must be
detached and on the CPU.
"""

from __future__ import annotations

import logging
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from napari.qt.threading import create_worker
from qtpy.QtCore import QObject, Signal

from lfm_studio.engine.progress import CancelledError, ProgressCallback

_log = logging.getLogger(__name__)

TaskFunction = Callable[[ProgressCallback, threading.Event], Any]


@dataclass(frozen=True)
class Outcome:
    """How a task ended: ``state`` is ``"done"`` (with ``value``), ``"cancelled"`` or ``"failed"`` (``message``)."""

    state: str
    value: Any = None
    message: str = ""
    details: str = ""
    seconds: float = 0.0


def _run(func: TaskFunction, report: ProgressCallback, cancel: threading.Event) -> Outcome:
    """Worker-thread body; never raises, so every ending reaches the GUI thread as one outcome."""
    start = time.perf_counter()
    try:
        if cancel.is_set():
            raise CancelledError("cancelled before it started")
        value = func(report, cancel)
    except CancelledError:
        return Outcome("cancelled", seconds=time.perf_counter() - start)
    except Exception as error:
        text = str(error) if isinstance(error, (ValueError, OSError)) else f"{type(error).__name__}: {error}"
        return Outcome(
            "failed", message=text, details=traceback.format_exc(), seconds=time.perf_counter() - start
        )
    if cancel.is_set():  # finished after the user asked to stop: honour the request
        return Outcome("cancelled", seconds=time.perf_counter() - start)
    return Outcome("done", value=value, seconds=time.perf_counter() - start)


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
        self._cancel = threading.Event()
        self._worker: Any = None
        self._started = False
        self.running = False
        self.outcome: Outcome | None = None
        if parent is not None:  # the owner going away stops the work at the next checkpoint
            event = self._cancel
            parent.destroyed.connect(lambda *_: event.set())

    def start(self) -> None:
        """Start the worker thread (once)."""
        if self._started:
            raise RuntimeError("a BackgroundTask runs once; create a new one")
        self._started = True
        worker = create_worker(
            _run, self._func, self._report, self._cancel, _start_thread=False, _ignore_errors=True
        )
        worker.returned.connect(self._on_returned)
        self._worker = worker
        self.running = True
        worker.start()

    def cancel(self) -> None:
        """Ask the task to stop at the engine's next checkpoint (between iterations, depths, lenslets)."""
        self._cancel.set()

    @property
    def cancel_requested(self) -> bool:
        return self._cancel.is_set()

    def _report(self, done: int, total: int, message: str) -> None:
        self.progressed.emit(int(done), int(total), str(message))  # queued: emitted on the worker thread

    def _on_returned(self, outcome: Outcome) -> None:
        self.running = False
        self.outcome = outcome
        self._worker = None
        if outcome.state == "failed":
            _log.debug("background task failed:\n%s", outcome.details)
        self.ended.emit(outcome)
