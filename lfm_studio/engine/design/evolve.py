"""Change one value deep inside a spec, getting a new, fully validated spec.

pydantic's ``model_copy(update=...)`` does not validate, so it could build a design
that breaks its invariants; :func:`evolve` rebuilds every spec on the path with
``model_validate``, so all checks (including the design-level ones) run again.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, TypeVar

from pydantic import BaseModel

from lfm_studio.engine.design.errors import DesignError

SpecT = TypeVar("SpecT", bound=BaseModel)


def rebuild(spec: SpecT, changes: dict[str, Any]) -> SpecT:
    """``spec`` with top-level fields replaced by ``changes``, validated again."""
    fields = type(spec).model_fields
    unknown = sorted(set(changes) - set(fields))
    if unknown:
        raise DesignError(f"{type(spec).__name__} has no field(s) {unknown}; known: {list(fields)}.")
    data = {name: getattr(spec, name) for name in fields}
    data.update(changes)
    return type(spec).model_validate(data)


def _set(node: Any, parts: Sequence[str], value: Any, where: str) -> Any:
    head, rest = parts[0], parts[1:]
    if isinstance(node, BaseModel):
        if head not in type(node).model_fields:
            hint = (
                " (a RegularMLASpec: edit pitch_um/shape, or convert it with .to_explicit())"
                if head == "lenslets"
                else ""
            )
            raise DesignError(
                f"{where or type(node).__name__} has no field {head!r}{hint}; known: {list(type(node).model_fields)}."
            )
        child = getattr(node, head)
        return rebuild(
            node, {head: _set(child, rest, value, f"{where}.{head}".lstrip(".")) if rest else value}
        )
    if isinstance(node, tuple):
        try:
            index = int(head)
            node[index]
        except (ValueError, IndexError):
            raise DesignError(f"{where} has {len(node)} items; {head!r} is not a valid index.") from None
        item = _set(node[index], rest, value, f"{where}.{head}") if rest else value
        return (*node[:index], item, *node[index + 1 :])
    raise DesignError(f"cannot go into {where} (a {type(node).__name__}) with {head!r}.")


def evolve(spec: SpecT, path: str | Sequence[str | int], value: Any) -> SpecT:
    """A new validated ``spec`` with the value at ``path`` replaced.

    Parameters
    ----------
    spec : any spec (a Design or one of its parts).
    path : dotted field path, tuple items by index: ``"objective.numerical_aperture"``,
        ``"mla.lenslets.3.focal_length_mm"``, ``"camera.pixel_count.1"``; or a sequence of parts.
    value : the new value (a number, a spec, a dict validated like a file...).

    Raises
    ------
    ValueError
        ``pydantic.ValidationError`` when the new value breaks an invariant, or
        :class:`DesignError` for a path that does not exist.
    """
    parts = path.split(".") if isinstance(path, str) else [str(p) for p in path]
    if not parts or any(p == "" for p in parts):
        raise DesignError(f"path must name a field, e.g. 'objective.numerical_aperture'; got {path!r}.")
    return _set(spec, parts, value, "")
