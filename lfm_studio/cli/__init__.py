"""The ``lfm-studio`` command line: one module per sub-command, :mod:`.commands` assembles them.

``lfm_studio.cli:main`` is the console entry point. GUI packages are imported only by the
``gui`` sub-command. This package module stays light (no torch): the heavy imports happen inside
:func:`main`, so a Ctrl+C while they load ends with a one-line message and :data:`INTERRUPTED`,
not a traceback.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

INTERRUPTED = 130
"""Exit status after Ctrl+C (128 + SIGINT), as the shell reports it."""


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``lfm-studio`` and ``python -m lfm_studio`` (:func:`lfm_studio.cli.commands.main`)."""
    try:
        from lfm_studio.cli.commands import main as run
    except KeyboardInterrupt:  # while torch and the engine load: nothing has started yet
        print("lfm-studio: interrupted while starting; nothing was done.", file=sys.stderr)
        return INTERRUPTED
    return run(argv)


def build_parser() -> Any:
    """The argument parser with every sub-command (:func:`lfm_studio.cli.commands.build_parser`)."""
    from lfm_studio.cli.commands import build_parser as build

    return build()


__all__ = ["INTERRUPTED", "build_parser", "main"]
