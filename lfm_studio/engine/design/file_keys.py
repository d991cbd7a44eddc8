"""Explain unknown keys in a design file: where they are and which schema version knew them."""

from __future__ import annotations

import typing
from typing import Any

from pydantic import BaseModel, ValidationError

from lfm_studio.engine.design.design import SCHEMA_VERSION, Design
from lfm_studio.engine.design.migrations import MIGRATIONS, RETIRED_KEYS


def _models_in(annotation: Any) -> list[type[BaseModel]]:
    """Spec classes a field annotation can hold (through Optional, tuple, Annotated, unions)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    found: list[type[BaseModel]] = []
    for arg in typing.get_args(annotation):
        for model in _models_in(arg):
            if model not in found:
                found.append(model)
    return found


def _locate(loc: tuple[Any, ...]) -> tuple[str, str, type[BaseModel] | None]:
    """For the parent part of an error location: (display path, plain dotted path, spec class there)."""
    model: type[BaseModel] | None = Design
    union: dict[str, type[BaseModel]] = {}
    shown: list[str] = []
    plain: list[str] = []
    for part in loc:
        if isinstance(part, int):
            if shown:
                shown[-1] += f"[{part}]"
            continue
        if part in union:  # the tag pydantic inserts for a discriminated union member
            model, union = union[part], {}
            continue
        shown.append(part)
        plain.append(part)
        field = model.model_fields.get(part) if model is not None else None
        models = _models_in(field.annotation) if field is not None else []
        model = models[0] if len(models) == 1 else None
        union = {m.model_fields["layout"].default: m for m in models} if len(models) > 1 else {}
    return ".".join(shown), ".".join(plain), model


def describe_unknown_keys(exc: ValidationError, *, file_version: int) -> str:
    """A sentence listing every unknown key of ``exc`` (empty if there is none)."""
    oldest = min(MIGRATIONS, default=SCHEMA_VERSION)
    notes = []
    for error in exc.errors():
        if error["type"] != "extra_forbidden":
            continue
        *parent, key = error["loc"]
        shown, plain, model = _locate(tuple(parent))
        where = f"{shown}.{key}" if shown else str(key)
        retired = RETIRED_KEYS.get((plain, str(key)))
        if retired is not None:
            version, replacement = retired
            note = (
                f"'{where}' is known to schema_version {version} (replaced by {replacement}); "
                f'set "schema_version": {version} to have the file migrated, or rename the key'
            )
        else:
            note = f"'{where}' is not known to any schema version ({oldest}-{SCHEMA_VERSION})"
        if model is not None:
            note += f"; keys known {'in ' + shown if shown else 'at the top level'}: {', '.join(model.model_fields)}"
        notes.append(note)
    if not notes:
        return ""
    return f"has {len(notes)} unknown key(s): " + ". ".join(notes) + ". Fix: remove or rename them."


def describe_invalid_values(exc: ValidationError) -> str:
    """One readable line per problem of ``exc`` (missing keys named with their place and the keys
    known there; other errors as ``place: message (got value)``), instead of pydantic's dump."""
    notes = []
    for error in exc.errors():
        *parent, key = error["loc"] or ("(top level)",)
        shown, _plain, model = _locate(tuple(parent))
        where = f"{shown}.{key}" if shown else str(key)
        if error["type"] == "missing":
            known = f" (keys of {shown or 'the top level'}: {', '.join(model.model_fields)})" if model else ""
            notes.append(f"the key '{where}' is missing{known}")
        else:
            value = repr(error.get("input"))
            value = value if len(value) <= 60 else value[:57] + "..."
            notes.append(f"'{where}': {error['msg']} (got {value})")
    return "; ".join(notes)


def has_own_fixes(exc: ValidationError) -> bool:
    """True when every problem of ``exc`` is a value error whose message carries its own ``Fix:``
    (no missing key, no pydantic type error): a generic "add or correct these keys" would only repeat."""
    return all(error["type"] != "missing" and "Fix:" in str(error["msg"]) for error in exc.errors())
