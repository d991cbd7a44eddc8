"""Progress reporting and cancellation for long engine loops.

Engine loops take ``progress`` (called as ``progress(done, total, message)``) and
``cancel`` (anything with ``is_set()``, e.g. ``threading.Event``, or a zero-argument
callable returning bool). Cancellation raises :class:`CancelledError` between units of
work, so the caller's previous result is never half-overwritten.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol


class CancelledError(Exception):
    """The caller asked a running computation to stop."""


class _Flag(Protocol):
    def is_set(self) -> bool: ...


ProgressCallback = Callable[[int, int, str], None]
CancelToken = _Flag | Callable[[], bool] | None


def is_cancelled(cancel: CancelToken) -> bool:
    """True when ``cancel`` says stop."""
    if cancel is None:
        return False
    if hasattr(cancel, "is_set"):
        return bool(cancel.is_set())
    return bool(cancel())


def checkpoint(
    cancel: CancelToken, progress: ProgressCallback | None, done: int, total: int, message: str
) -> None:
    """Report progress, then raise :class:`CancelledError` if asked to stop."""
    if progress is not None:
        progress(done, total, message)
    if is_cancelled(cancel):
        raise CancelledError(message)
