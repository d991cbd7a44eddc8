"""How ``lfm-studio`` talks on the terminal: design warnings as one-line notes, a closed stdout.

:func:`design_notes` shows a :class:`~lfm_studio.engine.design.DesignWarning` as
``lfm-studio COMMAND: note: MESSAGE`` on stderr, like the CLI's other notes, instead of
Python's ``FILE:LINE: DesignWarning: ...`` plus the source line, and lfm_studio's other warning
classes (e.g. a learned model's output that does not fit the frame) as ``lfm-studio COMMAND:
warning: MESSAGE``. Other packages' warnings keep Python's format. Only the command line does this; the engine warns as usual.

:func:`leave_quietly_on_broken_pipe` is the standard answer to a reader that stops early
(``lfm-studio metrics --json | head -1``): stdout is pointed at ``os.devnull`` so the
interpreter's final flush cannot fail again, and the command exits with
:data:`~lfm_studio.cli.errors.BROKEN_PIPE` without a traceback (the Python documentation,
"Note on SIGPIPE").
"""

from __future__ import annotations

import os
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TextIO

from lfm_studio.engine.design import DesignWarning


@contextmanager
def design_notes(command: str | None) -> Iterator[None]:
    """Within the block, print each ``DesignWarning`` as ``lfm-studio COMMAND: note: MESSAGE``."""
    default = warnings.showwarning

    def show(
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        file: TextIO | None = None,
        line: str | None = None,
    ) -> None:
        if issubclass(category, DesignWarning):
            print(f"lfm-studio {command or 'gui'}: note: {message}", file=file or sys.stderr)
        elif category.__module__.startswith("lfm_studio."):  # our own warnings carry their fix
            print(f"lfm-studio {command or 'gui'}: warning: {message}", file=file or sys.stderr)
        else:
            default(message, category, filename, lineno, file, line)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = default


def leave_quietly_on_broken_pipe() -> None:
    """After a ``BrokenPipeError`` on stdout: send the rest of stdout to ``os.devnull``."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # a replaced stdout (tests): nothing to redirect
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)
