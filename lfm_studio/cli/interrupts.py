"""What an interrupted (Ctrl+C) command kept, for its one-line message (exit 130).

Every output is written atomically, so an interrupt never leaves a partial file; but it may
come after an output was written (``calibrate`` wrote the calibration, not yet
``--design-out``) or while a resumable result grows (a video store's finished frames, a
study's finished trials). A handler wraps its work in :func:`on_interrupt` with a function
that says what was kept and how to continue; :func:`interrupt_message` words the line
``lfm-studio`` prints. Without such an account the message says that no output was written.
"""

from __future__ import annotations

import argparse
import functools
import os
import stat
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

NOTHING_WRITTEN = "no output was written."
RERUN_OVERWRITE = "Fix: run the same command again with --overwrite to write them all from one run."


def previous_store_unchanged(path: str | os.PathLike[str]) -> str:
    """What an interrupted ``--overwrite`` run of an existing store kept: the previous store, as it
    was (the replacement is built aside and dropped on an interrupt)."""
    return (
        f"the previous store {path} is unchanged (the replacement run was discarded). "
        "Fix: run the same command again to replace it."
    )


class Interrupted(KeyboardInterrupt):
    """A Ctrl+C with ``kept``: what the command kept and how to continue (one sentence or two)."""

    def __init__(self, kept: str) -> None:
        super().__init__(kept)
        self.kept = kept


def interrupt_message(command: str | None, interrupt: KeyboardInterrupt) -> str:
    """The line printed for ``interrupt`` of ``lfm-studio COMMAND``."""
    kept = interrupt.kept if isinstance(interrupt, Interrupted) else NOTHING_WRITTEN
    return f"lfm-studio {command}: interrupted; {kept}"


@contextmanager
def on_interrupt(describe: Callable[[], str | None]) -> Iterator[None]:
    """Turn a Ctrl+C inside the block into :class:`Interrupted` carrying ``describe()``: what was
    kept, or None when nothing was (the plain interrupt then propagates). ``describe`` runs after
    the interrupt; an error in it (e.g. an unreadable store) counts as nothing to say."""
    try:
        yield
    except Interrupted:
        raise
    except KeyboardInterrupt as interrupt:
        try:
            kept = describe()
        except Exception:
            kept = None
        if kept is None:
            raise
        raise Interrupted(kept) from interrupt


def _stamp(path: Path) -> tuple[int, int, int] | None:
    """``(inode, size, mtime in ns)`` of the file ``path`` (an atomic replace changes the inode);
    None when it is no regular file (missing, or a folder such as a video store)."""
    try:
        info = os.stat(path)
    except OSError:
        return None
    return (info.st_ino, info.st_size, info.st_mtime_ns) if stat.S_ISREG(info.st_mode) else None


@dataclass
class WatchedOutputs:
    """Output files and their state when the command started: which of them it has (re)written."""

    paths: tuple[Path, ...]
    before: dict[Path, tuple[int, int, int] | None] = field(default_factory=dict)

    @classmethod
    def of(cls, *paths: str | os.PathLike[str] | None) -> WatchedOutputs:
        """Watch ``paths`` (None entries, options not given, are skipped) from now on."""
        chosen = tuple(Path(p).expanduser() for p in paths if p is not None)
        return cls(chosen, {p: _stamp(p) for p in chosen})

    def written(self) -> list[Path]:
        """The watched files created or replaced since :meth:`of`."""
        return [p for p in self.paths if _stamp(p) is not None and _stamp(p) != self.before[p]]

    def account(self, fix: str, complete: str = "nothing else was to be written.") -> str | None:
        """What was kept: every output (``complete`` follows), some (``fix`` says how to write the
        rest), or None when none was written."""
        written = self.written()
        if not written:
            return None
        names = ", ".join(str(p) for p in written)
        missing = [str(p) for p in self.paths if p not in written]
        if not missing:
            return f"{names} had been written completely before it; {complete}"
        return f"{names} had been written before it, not {', '.join(missing)}. {fix}"


Handler = Callable[[argparse.Namespace], int]


def watching(
    *options: str, fix: str = RERUN_OVERWRITE, complete: str = "nothing else was to be written."
) -> Callable[[Handler], Handler]:
    """Decorate a handler whose output files are ``args.<option>`` (e.g. ``"out"``,
    ``"design_out"``): a Ctrl+C after one of them was written says which (then ``complete``
    when all were, ``fix`` for the others) instead of "no output was written"."""

    def decorate(handler: Handler) -> Handler:
        @functools.wraps(handler)
        def run(args: argparse.Namespace) -> int:
            outputs = WatchedOutputs.of(*(getattr(args, option, None) for option in options))
            with on_interrupt(lambda: outputs.account(fix, complete)):
                return handler(args)

        return run

    return decorate
