"""The MLA editor's model, Qt-free: pure edits of a lenslet list and an undo/redo history.

Every edit is a pure function ``tuple[LensletSpec, ...] -> tuple[LensletSpec, ...]``
that validates what it builds (a bad value raises :class:`ValueError` whose text is
the reason to show) and keeps the chosen :class:`Symmetry`. :class:`EditHistory`
stores snapshots (specs are immutable, so a snapshot is just the tuple).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import Any, Literal

from pydantic import ValidationError

from lfm_studio.engine.design import LensletSpec
from lfm_studio.engine.errors import error_text
from lfm_studio.widgets.mla_editor.symmetry import Point, PointIndex, Symmetry, apply, round_point
from lfm_studio.widgets.numeric_text import NumberRule, parse_number

Lenslets = tuple[LensletSpec, ...]
Field = Literal["x_um", "y_um", "diameter_um", "focal_length_mm"]
FIELDS: tuple[Field, ...] = ("x_um", "y_um", "diameter_um", "focal_length_mm")
FIELD_UNITS = {"x_um": "µm", "y_um": "µm", "diameter_um": "µm", "focal_length_mm": "mm"}
MAX_EXTENT_UM = 1e7  # 10 m: far beyond any MLA; a typo, not a design
LENSLET_RULES: dict[str, NumberRule] = {
    "x_um": NumberRule("x_um", -MAX_EXTENT_UM, MAX_EXTENT_UM, "µm", example=0.0),
    "y_um": NumberRule("y_um", -MAX_EXTENT_UM, MAX_EXTENT_UM, "µm", example=0.0),
    "diameter_um": NumberRule("diameter_um", 0.001, 1e6, "µm", example=1000.0),
    "focal_length_mm": NumberRule("focal_length_mm", 0.001, 1e5, "mm", example=26.0),
}
NO_SYMMETRY = Symmetry()


def lenslet(
    center_um: Point, diameter_um: float, focal_length_mm: float, shape: str = "circle"
) -> LensletSpec:
    """A validated :class:`LensletSpec`; raises :class:`ValueError` with the reason."""
    try:
        return LensletSpec(
            center_um=round_point(center_um),
            aperture_diameter_um=diameter_um,
            focal_length_mm=focal_length_mm,
            shape=shape,
        )
    except ValidationError as exc:
        raise ValueError(error_text(exc)) from None


def as_lenslets(items: Iterable[Any]) -> Lenslets:
    """Lenslet specs (or dicts as in a design file) as a validated tuple."""
    out = []
    for i, item in enumerate(items):
        if isinstance(item, LensletSpec):
            out.append(item)
            continue
        try:
            out.append(LensletSpec.model_validate(item))
        except ValidationError as exc:
            raise ValueError(f"lenslet {i}: {error_text(exc)}") from None
    return tuple(out)


def _with(lens: LensletSpec, **changes: Any) -> LensletSpec:
    values = {
        "center_um": lens.center_um,
        "diameter_um": lens.aperture_diameter_um,
        "focal_length_mm": lens.focal_length_mm,
        "shape": lens.shape,
        **changes,
    }
    return lenslet(**values)


def snap(p: Point, pitch_um: float) -> Point:
    """``p`` rounded to the nearest node of a square grid of ``pitch_um`` through the axis."""
    if not (math.isfinite(pitch_um) and pitch_um > 0):
        raise ValueError(f"snap pitch must be > 0 µm; got {pitch_um} µm. Fix: e.g. 100.")
    return round_point((round(p[0] / pitch_um) * pitch_um, round(p[1] / pitch_um) * pitch_um))


def with_partners(lenslets: Lenslets, indices: Iterable[int], symmetry: Symmetry = NO_SYMMETRY) -> list[int]:
    """``indices`` and all their symmetric partners, sorted."""
    found = set(indices)
    if not symmetry.is_identity:
        index = PointIndex([lens.center_um for lens in lenslets])
        for i in list(found):
            found.update(j for j, _ in symmetry.partners(index, lenslets[i].center_um, i))
    return sorted(found)


def move(
    lenslets: Lenslets,
    indices: Sequence[int],
    delta_um: Point,
    *,
    symmetry: Symmetry = NO_SYMMETRY,
    anchor: int | None = None,
    snap_pitch_um: float | None = None,
) -> Lenslets:
    """Move the lenslets ``indices`` by ``delta_um``; partners follow through their symmetry.

    With ``snap_pitch_um`` the ``anchor`` lenslet (default: the first index) lands on
    the grid and the others move by the same step. A lenslet on a mirror axis or on
    the rotation centre moves only along what its symmetry allows.
    """
    order = list(dict.fromkeys(([anchor] if anchor is not None else []) + list(indices)))
    if not order:
        return lenslets
    old = [lens.center_um for lens in lenslets]
    dx, dy = delta_um
    if snap_pitch_um is not None:
        a = old[order[0]]
        tx, ty = snap((a[0] + dx, a[1] + dy), snap_pitch_um)
        dx, dy = tx - a[0], ty - a[1]
    index = PointIndex([] if symmetry.is_identity else old)
    new = list(lenslets)
    done: set[int] = set()
    for i in order:
        if i in done:
            continue
        c = old[i]
        px, py = apply(symmetry.projector(c), (dx, dy))
        target = (c[0] + px, c[1] + py)
        for j, g in symmetry.partners(index, c, i):
            if j not in done:
                new[j] = _with(lenslets[j], center_um=apply(g, target))
                done.add(j)
    return tuple(new)


def add(
    lenslets: Lenslets,
    center_um: Point,
    *,
    diameter_um: float,
    focal_length_mm: float,
    shape: str = "circle",
    symmetry: Symmetry = NO_SYMMETRY,
) -> tuple[Lenslets, list[int]]:
    """Append a lenslet at ``center_um`` and its symmetric images; returns the list and the new indices."""
    added = [lenslet(p, diameter_um, focal_length_mm, shape) for p in symmetry.orbit(center_um)]
    return (*lenslets, *added), list(range(len(lenslets), len(lenslets) + len(added)))


def delete(lenslets: Lenslets, indices: Iterable[int], *, symmetry: Symmetry = NO_SYMMETRY) -> Lenslets:
    """The list without ``indices`` and their symmetric partners."""
    gone = set(with_partners(lenslets, indices, symmetry))
    return tuple(lens for i, lens in enumerate(lenslets) if i not in gone)


def set_value(
    lenslets: Lenslets,
    indices: Sequence[int],
    field: Field,
    value: float,
    *,
    symmetry: Symmetry = NO_SYMMETRY,
) -> Lenslets:
    """Set ``field`` (one of :data:`FIELDS`) of the lenslets ``indices`` (and their partners) to ``value``."""
    if field not in FIELDS:
        raise ValueError(f"field must be one of {', '.join(FIELDS)}; got {field!r}.")
    if not math.isfinite(value):
        raise ValueError(f"{field} must be a finite number in {FIELD_UNITS[field]}; got {value}.")
    out = lenslets
    if field in ("x_um", "y_um"):
        for i in indices:
            x, y = out[i].center_um
            delta = (value - x, 0.0) if field == "x_um" else (0.0, value - y)
            out = move(out, [i], delta, symmetry=symmetry)
        return out
    key = "diameter_um" if field == "diameter_um" else "focal_length_mm"
    targets = set(with_partners(lenslets, indices, symmetry))
    return tuple(_with(lens, **{key: value}) if i in targets else lens for i, lens in enumerate(lenslets))


def parse_value(field: Field, text: str) -> float:
    """A number typed into the table for ``field`` ("1.5", "1,5", "150 um"); ValueError with the reason.

    The same policy as every numeric field (:func:`~lfm_studio.widgets.numeric_text.parse_number`)
    with the ranges of :data:`LENSLET_RULES`.
    """
    if field not in FIELDS:
        raise ValueError(f"field must be one of {', '.join(FIELDS)}; got {field!r}.")
    return float(parse_number(text, LENSLET_RULES[field]))


def value_of(lens: LensletSpec, field: Field) -> float:
    """The value of ``field`` for ``lens`` (in the unit of the field name)."""
    return {
        "x_um": lens.center_um[0],
        "y_um": lens.center_um[1],
        "diameter_um": lens.aperture_diameter_um,
        "focal_length_mm": lens.focal_length_mm,
    }[field]


class EditHistory:
    """Undo/redo over snapshots of the lenslet list.

    Parameters
    ----------
    lenslets : the starting list.
    limit : the most undo steps kept (older ones are forgotten).
    """

    def __init__(self, lenslets: Lenslets, *, limit: int = 500) -> None:
        self._current = tuple(lenslets)
        self._undo: list[tuple[Lenslets, str]] = []
        self._redo: list[tuple[Lenslets, str]] = []
        self._limit = limit

    @property
    def current(self) -> Lenslets:
        """The list as it stands."""
        return self._current

    def push(self, lenslets: Lenslets, label: str = "edit") -> bool:
        """Make ``lenslets`` current (undoable as ``label``); False (nothing recorded) if unchanged."""
        lenslets = tuple(lenslets)
        if lenslets == self._current:
            return False
        self._undo.append((self._current, label))
        del self._undo[: -self._limit]
        self._redo.clear()
        self._current = lenslets
        return True

    def undo(self) -> Lenslets | None:
        """Step back; the restored list, or None if there is nothing to undo."""
        if not self._undo:
            return None
        previous, label = self._undo.pop()
        self._redo.append((self._current, label))
        self._current = previous
        return previous

    def redo(self) -> Lenslets | None:
        """Step forward again; the restored list, or None if there is nothing to redo."""
        if not self._redo:
            return None
        following, label = self._redo.pop()
        self._undo.append((self._current, label))
        self._current = following
        return following

    def can_undo(self) -> bool:
        """True if :meth:`undo` would change something."""
        return bool(self._undo)

    def can_redo(self) -> bool:
        """True if :meth:`redo` would change something."""
        return bool(self._redo)

    def undo_label(self) -> str:
        """What :meth:`undo` would revert ("" if nothing)."""
        return self._undo[-1][1] if self._undo else ""

    def redo_label(self) -> str:
        """What :meth:`redo` would re-apply ("" if nothing)."""
        return self._redo[-1][1] if self._redo else ""

    def reset(self, lenslets: Lenslets) -> None:
        """Start over from ``lenslets`` with an empty history."""
        self._current = tuple(lenslets)
        self._undo.clear()
        self._redo.clear()
