"""Refusals about files, raised before any work: outputs that must not be written, inputs that cannot be read.

:class:`OutputError` covers every reason not to write an output: it exists and
``overwrite`` was not given, it is one of the inputs (refused even with ``overwrite``:
a run must never destroy what it reads), its folder is missing or not writable, or
the disk is full. :class:`InputFileError` is a file that exists but is not a readable
TIFF (truncated, corrupt, another format). Both are ``ValueError`` subclasses, so
callers that report ``ValueError`` keep working; the command line gives each kind its
own exit code.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Iterable
from pathlib import Path


class OutputError(ValueError):
    """An output file must not or cannot be written (nothing was written)."""


class InputFileError(ValueError):
    """An input file exists but cannot be read as what it should be (truncated, corrupt, not a TIFF)."""


def _same_file(a: Path, b: Path) -> bool:
    if a.exists() and b.exists():
        return os.path.samefile(a, b)
    return a.resolve() == b.resolve()


def check_output(
    path: str | os.PathLike,
    *,
    overwrite: bool,
    inputs: Iterable[str | os.PathLike | None] = (),
    flag: str = "--out",
    tiff: bool = False,
) -> Path:
    """Refuse an output path before any work, with the reason and a fix; return it as a Path.

    Parameters
    ----------
    path : the output file.
    overwrite : whether an existing file (not an input) may be replaced.
    inputs : files the run reads; the output may never be one of them.
    flag : how the user named the output (for the message), e.g. ``"--truth"``.
    tiff : the output is a TIFF, so its name must end in ``.tif`` / ``.tiff`` (:func:`check_tiff_name`).
    """
    target = Path(path).expanduser()
    if tiff:
        check_tiff_name(target, flag=flag)
    for source in inputs:
        if source is not None and _same_file(target, Path(source).expanduser()):
            raise OutputError(
                f"{flag} {target} is also an input of this run; writing it would destroy the input "
                "(refused even with --overwrite). Fix: choose another output file name."
            )
    if target.is_dir():
        raise OutputError(f"{flag} {target} is a folder. Fix: give a file name, e.g. {target / 'out.tif'}.")
    if target.exists() and not overwrite:
        raise OutputError(f"{target} exists. Fix: choose another {flag} or pass --overwrite.")
    folder = target.parent
    if not folder.is_dir():
        raise OutputError(f"{flag} {target}: the folder {folder} does not exist. Fix: create it first.")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(not_writable_message(target))
    return target


TIFF_SUFFIXES = (".tif", ".tiff")
ZARR_SUFFIX = ".zarr"
"""What names a (OME-)Zarr store: ``run.zarr``, ``run.ome.zarr`` (the CLI's video outputs too)."""


def names_zarr_store(path: str | os.PathLike) -> bool:
    """True when ``path`` ends in ``.zarr`` (any case, a trailing ``/`` ignored)."""
    return os.fspath(path).rstrip("/").lower().endswith(ZARR_SUFFIX)


def zarr_store_path(text: str | os.PathLike) -> Path:
    """``text`` as an OME-Zarr store path: ``.ome.zarr`` added when it names no ``.zarr`` (what the
    studio's and the napari plugin's output fields make of a typed name)."""
    path = Path(text).expanduser()
    return path if names_zarr_store(path) else path.with_name(path.name + ".ome.zarr")


def check_tiff_name(path: str | os.PathLike, *, flag: str | None = None) -> Path:
    """Refuse a TIFF output whose name does not end in ``.tif`` / ``.tiff`` (other tools go by the
    suffix: ``v.png`` holding a TIFF opens nowhere); return the path. ``flag``: how the user
    named the output (e.g. ``"--out"``), put before the path in the message."""
    target = Path(path).expanduser()
    if target.suffix.lower() not in TIFF_SUFFIXES:
        named = f"{flag} {target}" if flag else str(target)
        raise OutputError(
            f"{named} would hold a TIFF, but its name does not end in .tif or .tiff, so other tools would "
            f"misread it. Nothing was written. Fix: name it {target.with_suffix('.tif').name}."
        )
    return target


def not_writable_message(target: Path) -> str:
    return (
        f"cannot write {target}: the folder {target.parent} is not writable (permission denied). "
        "Fix: choose an output in a folder you can write to, or change the folder's permissions."
    )


def output_os_error(target: Path, error: OSError) -> OutputError:
    """An :class:`OutputError` for an ``OSError`` raised while writing ``target`` (nothing was left behind)."""
    if isinstance(error, PermissionError) or error.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        return OutputError(not_writable_message(target))
    if error.errno in (errno.ENOSPC, errno.EDQUOT):
        return OutputError(
            f"cannot write {target}: no space left on the device of {target.parent} ({error.strerror}); "
            "nothing was written. Fix: free some space or write to another disk."
        )
    return OutputError(f"cannot write {target}: {error.strerror or error}. Nothing was written.")
