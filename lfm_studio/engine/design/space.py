"""Design spaces: named, bounded parameters over any field of a :class:`Design`, by dotted path.

A :class:`Parameter` names one value of a design (``objective.numerical_aperture``,
``relay.focal_length_mm``, ``mla.pitch_um``, ``mla.lenslets[3].center_um[0]``,
``mla.lattice``, ``pupil_phase.zernike_waves.4``: a Zernike coefficient of a design's
pupil phase mask, in waves; a term the design does not list reads as 0 and is created when
written) and the values it may take: ``low``/``high`` with an optional ``step``
(a grid) or ``points`` (that many evenly spaced values), or a list of ``choices``.
``*`` as an index sets every item (``mla.lenslets[*].focal_length_mm``), a comma list sets
those items together (``mla.lenslets[1,3,5].focal_length_mm``: a lenslet group, or lenslets
tied by symmetry). Values are in the
unit of the design field (its name's suffix: ``_mm``, ``_um``, ``_nm``; unitless otherwise).

A :class:`DesignSpace` is a tuple of parameters; :meth:`DesignSpace.apply` writes a point
(``{path: value}``) into a design and validates the result once with the design's own
checks (the model validation that :func:`~lfm_studio.engine.design.evolve` runs), so a
point that swaps two lenslets is judged as a whole, not by a transient overlap.
:meth:`DesignSpace.to_json` / :func:`space_from_json` give the ``space.json`` form
(docs/optimize.md).
"""

from __future__ import annotations

import itertools
import json
import math
import os
import re
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lfm_studio.engine.design.design import Design

Value = float | int | str | bool
Point = dict[str, Value]

UNIT_SUFFIXES = {"_mm": "mm", "_um": "um", "_nm": "nm", "_e": "e-", "_adu": "ADU", "_waves": "waves"}
"""Field-name suffixes and the unit they mean (fields without one are unitless)."""

_INDEX = re.compile(r"\[([^\]]*)\]")


def path_parts(path: str) -> list[str]:
    """``"mla.lenslets[3].center_um[0]"`` -> ``["mla", "lenslets", "3", "center_um", "0"]``."""
    parts = _INDEX.sub(r".\1", path).split(".")
    if not path or any(p == "" for p in parts):
        raise ValueError(
            f"parameter path must name a design field, e.g. 'objective.numerical_aperture' or "
            f"'mla.lenslets[3].center_um[0]'; got {path!r}."
        )
    return parts


def unit_of(path: str) -> str:
    """Unit of the field ``path`` names (from the last field name's suffix; "" when unitless)."""
    names = [p for p in path_parts(path) if not _is_index(p)]
    last = names[-1]
    for suffix, unit in UNIT_SUFFIXES.items():
        if last.endswith(suffix):
            return unit
    return ""


def _is_index(part: str) -> bool:
    return part == "*" or all(p.strip().lstrip("-").isdigit() for p in part.split(","))


def _indices(part: str, length: int) -> list[int]:
    """Item indices named by ``part``: ``*`` (all), ``3``, ``-1`` or ``1,3,5``."""
    return list(range(length)) if part == "*" else [int(p) for p in part.split(",")]


def _get(node: Any, parts: Sequence[str], path: str) -> list[Any]:
    """Every value at ``parts`` under ``node`` (plain data from ``model_dump``); ``*`` and lists fan out."""
    if not parts:
        return [node]
    head, rest = parts[0], parts[1:]
    if isinstance(node, dict):
        if head not in node:
            raise ValueError(f"parameter path {path!r}: no field {head!r} here; known: {sorted(node)}.")
        return _get(node[head], rest, path)
    if isinstance(node, list | tuple):
        if not (_is_index(head) and all(-len(node) <= i < len(node) for i in _indices(head, len(node)))):
            raise ValueError(
                f"parameter path {path!r}: {head!r} is not an index of a list of {len(node)} items."
            )
        return [v for i in _indices(head, len(node)) for v in _get(node[i], rest, path)]
    raise ValueError(f"parameter path {path!r}: cannot go into a {type(node).__name__} with {head!r}.")


def _set(node: Any, parts: Sequence[str], value: Any) -> Any:
    """A copy of plain data ``node`` with ``value`` at ``parts`` (``*`` sets every item)."""
    if not parts:
        return value
    head, rest = parts[0], parts[1:]
    if isinstance(node, dict):
        return {**node, head: _set(node[head], rest, value)}
    items = list(node)
    for i in _indices(head, len(items)):
        items[i] = _set(items[i], rest, value)
    return items


_ZERNIKE = ("pupil_phase", "zernike_waves")


def _with_zernike_term(data: dict[str, Any], parts: Sequence[str]) -> dict[str, Any]:
    """``data`` (a design's plain data) with the Zernike term ``parts`` names listed, at 0 waves if
    it was not: a coefficient path reads as 0 (no mask) on a design without that term and creates
    the term when written. Other paths: ``data`` unchanged."""
    if len(parts) != 3 or tuple(parts[:2]) != _ZERNIKE or not parts[2].isdigit():
        return data
    phase = dict(data.get("pupil_phase") or {})
    terms = dict(phase.get("zernike_waves") or {})
    if parts[2] in terms:
        return data
    return {**data, "pupil_phase": {**phase, "zernike_waves": {**terms, parts[2]: 0.0}}}


@dataclass(frozen=True)
class Parameter:
    """One free value of a design.

    Attributes
    ----------
    path : dotted path to the field (see the module docstring).
    low, high : bounds (inclusive), in :attr:`unit`; None with ``choices``.
    step : grid spacing in :attr:`unit` (None: continuous, or ``points`` values).
    points : number of evenly spaced grid values from ``low`` to ``high`` (instead of ``step``).
    choices : the allowed values (numbers, strings, booleans) instead of bounds.
    integer : values are integers (e.g. ``mla.shape[1]``).
    log : sample on a log scale (Optuna samplers; the grid stays as given).
    """

    path: str
    low: float | None = None
    high: float | None = None
    step: float | None = None
    points: int | None = None
    choices: tuple[Value, ...] | None = None
    integer: bool = False
    log: bool = False

    def __post_init__(self) -> None:
        path_parts(self.path)
        where = f"parameter {self.path!r}"
        if self.choices is not None:
            if self.low is not None or self.high is not None or self.step is not None:
                raise ValueError(f"{where}: give either choices or low/high, not both.")
            if not self.choices:
                raise ValueError(f"{where}: choices is empty. Fix: list at least one value.")
            bad = [c for c in self.choices if not isinstance(c, int | float | str | bool)]
            if bad:
                raise ValueError(
                    f"{where}: choices must be numbers, strings or booleans; got {bad[:3]}. "
                    "Fix: free each coordinate as its own parameter (e.g. center_um[0] and center_um[1])."
                )
            return
        if self.low is None or self.high is None:
            raise ValueError(f"{where} needs low and high (or choices). Fix: e.g. low 0.5, high 1.0.")
        if not (math.isfinite(self.low) and math.isfinite(self.high) and self.low <= self.high):
            raise ValueError(f"{where}: low must be <= high (finite); got low {self.low}, high {self.high}.")
        if self.step is not None and not self.step > 0:
            raise ValueError(f"{where}: step must be > 0 {self.unit}; got {self.step}.")
        if self.points is not None and not (isinstance(self.points, int) and self.points >= 1):
            raise ValueError(f"{where}: points must be an integer >= 1; got {self.points!r}.")
        if self.step is not None and self.points is not None:
            raise ValueError(f"{where}: give step or points, not both.")
        if self.log and self.low <= 0:
            raise ValueError(f"{where}: log scale needs low > 0; got {self.low}.")

    @property
    def unit(self) -> str:
        """Unit of the values (the design field's)."""
        return unit_of(self.path)

    @property
    def parts(self) -> list[str]:
        return path_parts(self.path)

    def grid(self) -> tuple[Value, ...]:
        """The values an exhaustive search tries, in order."""
        if self.choices is not None:
            return self.choices
        low, high = float(self.low), float(self.high)  # type: ignore[arg-type]
        if self.step is not None:
            count = math.floor((high - low) / self.step + 1e-9) + 1
            values = [low + i * self.step for i in range(count)]
        elif self.points is not None:
            values = (
                [low]
                if self.points == 1
                else [low + (high - low) * i / (self.points - 1) for i in range(self.points)]
            )
        else:
            raise ValueError(
                f"parameter {self.path!r} is continuous (no step, points or choices): a grid cannot list it. "
                'Fix: add "step" or "points", or use a sampler (tpe, cmaes, random).'
            )
        return tuple(round(v) if self.integer else round(v, 12) for v in values)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"path": self.path}
        for name in ("low", "high", "step", "points"):
            if getattr(self, name) is not None:
                out[name] = getattr(self, name)
        if self.choices is not None:
            out["choices"] = list(self.choices)
        if self.integer:
            out["integer"] = True
        if self.log:
            out["log"] = True
        out["unit"] = self.unit
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Parameter:
        known = {"path", "low", "high", "step", "points", "choices", "integer", "log", "unit"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(
                f"space parameter {data.get('path', '?')!r} has unknown key(s) {unknown}; known: {sorted(known)}."
            )
        if "path" not in data:
            raise ValueError(
                f'space parameter {dict(data)} has no "path". Fix: e.g. "path": "objective.numerical_aperture".'
            )
        param = cls(
            path=str(data["path"]),
            low=data.get("low"),
            high=data.get("high"),
            step=data.get("step"),
            points=data.get("points"),
            choices=tuple(data["choices"]) if data.get("choices") is not None else None,
            integer=bool(data.get("integer", False)),
            log=bool(data.get("log", False)),
        )
        if "unit" in data and data["unit"] != param.unit:
            raise ValueError(
                f"space parameter {param.path!r} says unit {data['unit']!r}, but the design field is in "
                f'{param.unit or "no unit"!r}. Fix: give the values in {param.unit or "no unit"!r} (or drop "unit").'
            )
        return param


@dataclass(frozen=True)
class DesignSpace:
    """The free parameters of a search, in order (paths must be distinct)."""

    parameters: tuple[Parameter, ...]
    description: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        if not self.parameters:
            raise ValueError("a design space needs at least one parameter.")
        paths = [p.path for p in self.parameters]
        duplicated = sorted({p for p in paths if paths.count(p) > 1})
        if duplicated:
            raise ValueError(f"design space lists {duplicated} more than once. Fix: keep one entry per path.")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.path for p in self.parameters)

    def check_paths(self, design: Design) -> None:
        """Raise ``ValueError`` naming any path that does not exist in ``design``."""
        data = design.model_dump(mode="json")
        for param in self.parameters:
            _get(_with_zernike_term(data, param.parts), param.parts, param.path)

    def values_of(self, design: Design) -> Point:
        """The design's current values at each path (a ``*`` path gives its first item's)."""
        data = design.model_dump(mode="json")
        return {p.path: _get(_with_zernike_term(data, p.parts), p.parts, p.path)[0] for p in self.parameters}

    def apply(self, design: Design, point: Mapping[str, Value]) -> Design:
        """``design`` with ``point`` written in and validated once.

        Raises ``ValueError`` (``DesignError`` or pydantic's ``ValidationError``) when the
        result breaks a design invariant, or for a path that is not in the space.
        """
        extra = sorted(set(point) - set(self.names))
        if extra:
            raise ValueError(f"point has paths {extra} that are not in the design space {list(self.names)}.")
        data = design.model_dump(mode="json")
        for param in self.parameters:
            if param.path in point:
                data = _with_zernike_term(data, param.parts)  # a new term is created at its value
                _get(data, param.parts, param.path)  # the path exists (clear message if not)
                data = _set(data, param.parts, point[param.path])
        return type(design).model_validate(data)

    def grid(self) -> Iterator[Point]:
        """Every grid point, the last parameter varying fastest."""
        names = self.names
        for values in itertools.product(*(p.grid() for p in self.parameters)):
            yield dict(zip(names, values, strict=True))

    def grid_size(self) -> int:
        return math.prod(len(p.grid()) for p in self.parameters)

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"parameters": [p.to_dict() for p in self.parameters]}
        if self.description:
            out["description"] = self.description
        return out

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)


def space_from_dict(data: Mapping[str, Any], *, origin: str = "design space") -> DesignSpace:
    """A :class:`DesignSpace` from its JSON form (``{"parameters": [...]}``)."""
    if not isinstance(data, Mapping) or not isinstance(data.get("parameters"), list):
        raise ValueError(f'{origin} must be a JSON object with a "parameters" list (docs/optimize.md).')
    try:
        params = tuple(Parameter.from_dict(p) for p in data["parameters"])
        return DesignSpace(params, description=str(data.get("description", "")))
    except (TypeError, ValueError) as error:
        raise ValueError(f"{origin}: {error}") from error


def space_from_json(text: str, *, origin: str = "design space") -> DesignSpace:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise ValueError(
            f"{origin} is not valid JSON: {error}. Fix: see docs/optimize.md for the format."
        ) from error
    return space_from_dict(data, origin=origin)


def load_space(path: str | os.PathLike[str]) -> DesignSpace:
    """Read a ``space.json`` file."""
    target = Path(path).expanduser()
    if not target.is_file():
        raise FileNotFoundError(f"--space {target}: no such file. Fix: give the path to a space JSON file.")
    return space_from_json(target.read_text(encoding="utf-8"), origin=str(target))


def point_key(point: Mapping[str, Value]) -> str:
    """A canonical string of a point (sorted paths, floats to 12 significant digits): equal points, equal keys."""

    def norm(v: Value) -> Value:
        return float(f"{v:.12g}") if isinstance(v, float) else v

    return json.dumps({k: norm(point[k]) for k in sorted(point)}, sort_keys=True)
