"""Errors and warnings raised by design specs, and the small checks that raise them.

Every message names the parameter (as it appears in a design file, with its unit
suffix), the value it got, the limit, and a fix. Errors are ``ValueError``
subclasses; inside a pydantic validator they arrive wrapped in a
``pydantic.ValidationError`` (itself a ``ValueError``) whose text keeps ours and
adds the location (e.g. ``objective``).
"""

from __future__ import annotations

import math
import warnings


class DesignError(ValueError):
    """A design violates a physical or geometric invariant."""


class DesignFileError(DesignError):
    """A design file (or JSON text) cannot be read: not JSON, unknown keys, bad version."""


class DesignWarning(UserWarning):
    """A design is valid but questionable (overlapping sub-images, undersampling...)."""


def fmt(value: float) -> str:
    """A number as people read it: 6 significant digits, no trailing noise."""
    return f"{value:.6g}"


def warn_design(message: str) -> None:
    """Emit a :class:`DesignWarning` with ``message``."""
    warnings.warn(message, DesignWarning, stacklevel=2)


def require_positive(name: str, value: float, unit: str, fix: str) -> None:
    """Raise :class:`DesignError` unless ``value`` is a finite number > 0.

    Parameters
    ----------
    name : the parameter as written in a design file, e.g. ``"pixel_pitch_um"``.
    value : the value, in ``unit``.
    unit : unit shown in the message (``""`` for unitless).
    fix : how to correct it; appended as ``Fix: ...``.
    """
    if not (math.isfinite(value) and value > 0.0):
        u = f" {unit}" if unit else ""
        raise DesignError(f"{name} must be a finite number > 0{u}; got {fmt(value)}{u}. Fix: {fix}")


def require_finite(name: str, value: float, unit: str, fix: str) -> None:
    """Raise :class:`DesignError` unless ``value`` is finite (not NaN or inf)."""
    if not math.isfinite(value):
        u = f" {unit}" if unit else ""
        raise DesignError(f"{name} must be finite; got {fmt(value)}{u}. Fix: {fix}")
