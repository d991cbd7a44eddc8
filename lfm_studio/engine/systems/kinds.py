"""The system kinds and the one place that reads the design-file word ``design.kind``.

:func:`kind_of` maps a design to its :class:`~.kinds_base.SystemKind` object
(:data:`FOURIER` or :data:`CONVENTIONAL`); :func:`kind_named` maps the word itself
(e.g. from a calibration file); :func:`stack_kind` tells which kind a PSF stack's layout
belongs to (lenslet patterns: conventional; per-depth PSFs, simulated or measured:
shift-invariant, built like a Fourier stack). Callers then use the object's methods and
capability flags, never the string.
"""

from __future__ import annotations

from typing import Any

from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.systems.kinds_base import ImagingSetup, Projector, SystemKind
from lfm_studio.engine.systems.kinds_conventional import CONVENTIONAL
from lfm_studio.engine.systems.kinds_fourier import FOURIER

__all__ = [
    "CONVENTIONAL",
    "FOURIER",
    "KINDS",
    "KIND_NAMES",
    "ImagingSetup",
    "Projector",
    "SystemKind",
    "kind_named",
    "kind_of",
    "stack_kind",
]

KINDS: tuple[SystemKind, ...] = (FOURIER, CONVENTIONAL)
KIND_NAMES: tuple[str, ...] = tuple(kind.name for kind in KINDS)
_BY_NAME = {kind.name: kind for kind in KINDS}


def kind_named(name: str) -> SystemKind:
    """The kind whose design-file word is ``name``."""
    kind = _BY_NAME.get(name) if isinstance(name, str) else None
    if kind is None:
        raise ValueError(f"system kind must be one of {', '.join(map(repr, KIND_NAMES))}; got {name!r}.")
    return kind


def kind_of(design: Any) -> SystemKind:
    """The kind of ``design`` (anything with a ``kind`` word: a Design, a calibration record)."""
    name = getattr(design, "kind", None)
    if name is None:
        raise ValueError(
            f"kind_of needs a design with a 'kind' ({', '.join(map(repr, KIND_NAMES))}); "
            f"got a {type(design).__name__}."
        )
    return kind_named(name)


def stack_kind(stack: PSFStack) -> SystemKind:
    """The kind whose projector fits ``stack``: :data:`CONVENTIONAL` for lenslet patterns
    (``stack.patterns``), else :data:`FOURIER` (shift-invariant per-depth PSFs, also measured ones)."""
    return FOURIER if stack.shift_invariant else CONVENTIONAL
