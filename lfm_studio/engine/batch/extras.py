"""The optional ``scale`` extra (Dask, Zarr, OME-Zarr): checked once, with the install line.

The engine core never imports these; :mod:`lfm_studio.engine.batch` does, through
:func:`require_scale`, so a missing package is a named error that says how to install it.
"""

from __future__ import annotations

import importlib

#: What ``pip install "lfm-studio[scale]"`` installs (import names).
SCALE_MODULES = ("dask", "distributed", "zarr", "ome_zarr")
INSTALL_HINT = 'pip install "lfm-studio[scale]"'


class MissingExtraError(ImportError):
    """A package of an optional extra is not installed; the message says how to install it."""


def require_scale() -> None:
    """Import every module of the ``scale`` extra, or raise :class:`MissingExtraError` naming the missing ones."""
    missing = []
    for name in SCALE_MODULES:
        try:
            importlib.import_module(name)
        except ImportError:
            missing.append(name)
    if missing:
        raise MissingExtraError(
            f"video reconstruction and scale-out need {', '.join(missing)} (not installed). "
            f"Fix: {INSTALL_HINT}"
        )
