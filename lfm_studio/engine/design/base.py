"""The base of every spec, and the one place where design units become SI.

Design files and specs use the units people think in, visible in the field name
(``wavelength_nm``, ``pixel_pitch_um``, ``focal_length_mm``). The engine works in SI
metres. Specs expose SI values as properties (``spec.wavelength``,
``spec.focal_length``) that all go through :func:`si` below, so the conversion
factors live in one place (:mod:`lfm_studio.engine.units`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Literal

from pydantic import BaseModel, ConfigDict

from lfm_studio.engine import units

Unit = Literal["nm", "um", "mm", "m"]

_SCALE: dict[str, float] = {"nm": units.nm, "um": units.um, "mm": units.mm, "m": units.m}


def si(value: float, unit: Unit) -> float:
    """``value`` given in ``unit`` ("nm", "um", "mm" or "m") as metres."""
    return float(value) * _SCALE[unit]


def si_pair(values: Sequence[float], unit: Unit) -> tuple[float, float]:
    """An ``(x, y)`` pair given in ``unit`` as metres."""
    return (si(values[0], unit), si(values[1], unit))


class SpecModel(BaseModel):
    """Immutable, validated description of one physical part.

    ``frozen=True``: change a spec by building a new one (:func:`~lfm_studio.engine.design.evolve`
    or ``Design.updated``), never in place; ``extra="forbid"``: a misspelt key is an error,
    not silently ignored. Note that pydantic's ``model_copy(update=...)`` skips validation:
    do not use it to change a spec.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")
