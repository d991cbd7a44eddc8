"""Turn field edits into a new validated design, or into the reason it was refused (Qt-free).

Several fields may hold values not yet in force (an NA above the immersion index
waits for the index to be raised), so an edit is applied together with the other
pending values in ONE validation (:meth:`Design.updated` on each top-level part), and
either everything is accepted or nothing is. Design warnings raised while validating
are collected, not printed. Refusals and warnings are worded as the studio shows them
(:func:`studio_text`): parameters by the labels of the parameter panel's fields and
micrometres as "µm"; the engine's messages (CLI, files) keep the keys and "um".
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pydantic import BaseModel

from lfm_studio.engine.design import Design, DesignWarning
from lfm_studio.engine.errors import error_text
from lfm_studio.ui.field_specs import in_field_labels
from lfm_studio.widgets.numeric_text import shown_units_in


def studio_text(message: str) -> str:
    """A design check's ``message`` in the studio's words: field labels for keys, "µm" for "um"."""
    return shown_units_in(in_field_labels(message))


@dataclass(frozen=True)
class EditOutcome:
    """The result of :func:`try_changes`: a design (accepted) or an error message (refused)."""

    design: Design | None
    error: str | None = None
    warnings: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return self.design is not None


def read_path(spec: Any, path: str) -> Any:
    """The value at dotted ``path`` in ``spec`` (tuple items by index), e.g. ``"camera.pixel_count.0"``."""
    node = spec
    for part in path.split("."):
        node = _child(node, part)
    return node


def read_path_or_none(spec: Any, path: str) -> Any:
    """:func:`read_path`, or None where a part of ``path`` is absent (a conventional design's ``relay``)."""
    node = spec
    for part in path.split("."):
        if node is None:
            return None
        node = _child(node, part)
    return node


def _child(node: Any, part: str) -> Any:
    """Item ``part`` of a tuple (by index), else attribute ``part``."""
    return node[int(part)] if isinstance(node, tuple) else getattr(node, part)


def _plain(value: Any) -> Any:
    return value.model_dump() if isinstance(value, BaseModel) else value


def _set_in(node: Any, parts: Sequence[str], value: Any) -> Any:
    """A copy of plain ``node`` (dicts, tuples, lists) with ``value`` at ``parts``."""
    head, rest = parts[0], parts[1:]
    if isinstance(node, (tuple, list)):
        items = list(node)
        index = int(head)
        items[index] = _set_in(_plain(items[index]), rest, value) if rest else value
        return tuple(items)
    if not isinstance(node, dict):
        raise KeyError(f"cannot set {'.'.join(parts)} inside a {type(node).__name__}")
    out = dict(node)
    out[head] = _set_in(_plain(out.get(head)), rest, value) if rest else value
    return out


def apply_changes(design: Design, changes: Mapping[str, Any]) -> Design:
    """A new validated design with every ``path -> value`` of ``changes`` applied at once.

    Raises ``ValueError`` (a pydantic ``ValidationError`` or
    :class:`~lfm_studio.engine.design.DesignError`) when the result breaks an invariant.
    """
    grouped: dict[str, Any] = {}
    for path, value in changes.items():
        head, *rest = path.split(".")
        if head not in type(design).model_fields:
            raise KeyError(f"Design has no field {head!r} (path {path!r})")
        if not rest:
            grouped[head] = value
            continue
        base = grouped[head] if head in grouped else _plain(getattr(design, head))
        grouped[head] = _set_in(base, rest, value)
    return design.updated(**grouped)


def try_changes(design: Design, changes: Mapping[str, Any]) -> EditOutcome:
    """:func:`apply_changes` that never raises: the new design with its warnings, or the reason."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DesignWarning)
        try:
            new = apply_changes(design, changes)
        except (ValueError, KeyError, TypeError) as error:
            return EditOutcome(None, studio_text(error_text(error)))
    return EditOutcome(new, None, _warning_texts(caught))


def _warning_texts(caught: Sequence[warnings.WarningMessage]) -> tuple[str, ...]:
    """The distinct design warnings among ``caught``, in the studio's words."""
    found = (str(w.message) for w in caught if issubclass(w.category, DesignWarning))
    return tuple(dict.fromkeys(studio_text(text) for text in found))


def with_design_warnings(load: Callable[..., Design], *args: Any) -> tuple[Design, tuple[str, ...]]:
    """``load(*args)`` (e.g. :func:`~lfm_studio.engine.design.load_design`) and the design warnings it raised."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DesignWarning)
        design = load(*args)
    return design, _warning_texts(caught)


def design_warnings(design: Design) -> tuple[str, ...]:
    """The design warnings ``design`` raises when validated again (e.g. after loading a file)."""
    outcome = try_changes(design, {})
    return outcome.warnings
