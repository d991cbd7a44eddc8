"""Input files named on the command line: a missing one is refused with the option that named it.

``require_file("--psf", path, "a PSF stack TIFF from 'lfm-studio simulate'")`` raises
``FileNotFoundError("--psf nope.tif: no such file. Fix: give the path to a PSF stack TIFF ...")``,
which ``cli.main`` prints as a usage error (exit 2), instead of the reader's bare
"No such TIFF file: nope.tif" that does not say which option was wrong.
"""

from __future__ import annotations

import os
from pathlib import Path


def require_file(option: str, path: str | os.PathLike[str] | None, what: str) -> None:
    """Raise ``FileNotFoundError`` naming ``option`` and ``path`` unless ``path`` is a file.

    ``what`` completes "Fix: give the path to ...". ``None`` (an option not given) passes.
    A folder is refused too (it is not the file the option reads).
    """
    if path is None:
        return
    target = Path(path).expanduser()
    if target.is_file():
        return
    problem = "a folder, not a file" if target.is_dir() else "no such file"
    raise FileNotFoundError(f"{option} {path}: {problem}. Fix: give the path to {what}.")
