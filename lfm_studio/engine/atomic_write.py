"""Atomic, overwrite-safe file writing.

The file is written to a temporary file in the destination folder, flushed and
fsynced, then moved over the destination with ``os.replace`` (atomic on POSIX and
Windows within one file system). A reader therefore sees either the old file or
the complete new one; a failure leaves the old file untouched and removes the
temporary file.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO


def atomic_write(
    path: str | os.PathLike, write: Callable[[BinaryIO], object], *, overwrite: bool = False
) -> Path:
    """Write a file atomically through ``write(fh)`` and return its path.

    Parameters
    ----------
    path : destination file.
    write : called with a binary, seekable file handle open on the temporary file.
    overwrite : replace an existing file; without it an existing ``path`` raises
        ``FileExistsError`` naming it, before anything is written.
    """
    target = Path(path).expanduser()
    if target.is_dir():
        raise IsADirectoryError(errno.EISDIR, f"{target} is a folder. Fix: give a file name", str(target))
    if target.exists() and not overwrite:
        raise FileExistsError(
            errno.EEXIST, f"{target} already exists. Fix: pass overwrite=True to replace it", str(target)
        )
    folder = target.parent
    if not folder.is_dir():
        raise FileNotFoundError(
            errno.ENOENT, f"folder {folder} does not exist. Fix: create it first", str(folder)
        )
    # mkstemp makes the file private (0600); give it the old file's mode or rw-r--r--.
    mode = target.stat().st_mode & 0o777 if target.exists() else 0o644
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=folder)
    os.close(fd)
    try:
        os.chmod(tmp_name, mode)
        with open(tmp_name, "wb") as fh:  # a named handle: tifffile needs fh.name
            write(fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp_name, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        raise
    _fsync_folder(folder)
    return target


def _fsync_folder(folder: Path) -> None:
    """Make the rename durable where the platform allows it (not on Windows)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
