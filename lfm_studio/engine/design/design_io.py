"""Design files: human-readable JSON with a schema version and units in the key names.

Writing is atomic (temporary file in the same folder, flush, fsync, ``os.replace``)
and never overwrites a file unless asked. Reading reports, with the file name:
text that is not JSON, unknown keys (listed, with the schema version that knew
them), files from a newer lfm_studio, and migrates files from older versions
(:mod:`lfm_studio.engine.design.migrations`).
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from lfm_studio.engine.atomic_write import atomic_write
from lfm_studio.engine.design.design import SCHEMA_VERSION, Design
from lfm_studio.engine.design.errors import DesignFileError
from lfm_studio.engine.design.file_keys import describe_invalid_values, describe_unknown_keys, has_own_fixes
from lfm_studio.engine.design.migrations import migrate

_INLINE_WIDTH = 120  # a list or list item (e.g. one lenslet) stays on one line up to this many characters


def _scalar(value: Any) -> bool:
    return value is None or isinstance(value, (bool, int, float, str))


def _flat(value: Any) -> bool:
    """A scalar, a list of scalars, or a dict of those: small enough to write on one line."""
    if isinstance(value, list):
        return all(_scalar(v) for v in value)
    if isinstance(value, dict):
        return all(_scalar(v) or (isinstance(v, list) and all(_scalar(x) for x in v)) for v in value.values())
    return _scalar(value)


def _format(value: Any, level: int) -> str:
    """JSON with indent 2, where short lists and list items (one lenslet, a pair) stay on one line."""
    pad, inner = "  " * level, "  " * (level + 1)
    line = json.dumps(value, separators=(", ", ": "), allow_nan=False)
    if (
        _scalar(value)
        or not value
        or (_flat(value) and isinstance(value, list) and len(line) <= _INLINE_WIDTH)
    ):
        return line
    if isinstance(value, dict):
        items = [f"{inner}{json.dumps(k)}: {_format(v, level + 1)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + pad + "}"
    items = []
    for item in value:
        text = json.dumps(item, separators=(", ", ": "), allow_nan=False)
        items.append(
            inner + (text if _flat(item) and len(text) <= _INLINE_WIDTH else _format(item, level + 1))
        )
    return "[\n" + ",\n".join(items) + "\n" + pad + "]"


def design_to_json(design: Design) -> str:
    """The design as JSON text: indent 2, one lenslet per line, keys in field order, newline at the end."""
    if not isinstance(design, Design):
        raise TypeError(f"design must be a Design; got {type(design).__name__}.")
    return _format(design.model_dump(mode="json"), 0) + "\n"


def design_from_json(text: str, *, origin: str = "design JSON") -> Design:
    """Read a design from JSON text, migrating older schema versions.

    Parameters
    ----------
    text : the JSON document.
    origin : how to name the source in messages (a file path, a preset name).

    Raises
    ------
    DesignFileError
        Not JSON, not an object, missing/invalid/newer ``schema_version``, unknown keys,
        or values that break the design's invariants (the message keeps pydantic's
        location and our parameter / value / fix text).
    """
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise DesignFileError(
            f"{origin} is not valid JSON: {exc.msg} at line {exc.lineno}, column {exc.colno}. "
            "Fix: correct the file (a design file is a JSON object), or re-save it from lfm_studio."
        ) from exc
    if not isinstance(data, dict):
        raise DesignFileError(f"{origin} must hold a JSON object (a design); got a {type(data).__name__}.")
    version = data.get("schema_version")
    if (
        "schema_version" not in data
        or isinstance(version, bool)
        or not isinstance(version, int)
        or version < 0
    ):
        raise DesignFileError(
            f"{origin} needs an integer schema_version >= 0; got {version!r}. "
            f'Fix: add "schema_version": {SCHEMA_VERSION} if it was written for this lfm_studio.'
        )
    if version > SCHEMA_VERSION:
        raise DesignFileError(
            f"{origin} was written by a newer lfm_studio (schema_version {version}); this lfm_studio reads "
            f"schema_version {SCHEMA_VERSION} and older. Fix: upgrade lfm_studio (pip install -U lfm-studio)."
        )
    data = migrate(data, origin=origin)
    try:
        return Design.model_validate(data)
    except ValidationError as exc:
        unknown = describe_unknown_keys(exc, file_version=version)
        if unknown:
            raise DesignFileError(f"{origin} (schema_version {version}) {unknown}") from exc
        generic = (
            ""
            if has_own_fixes(exc)
            else " Fix: add or correct these keys (compare with a preset: resources/designs/*.json, "
            "or save one with lfm-studio gui)."
        )
        raise DesignFileError(
            f"{origin} does not describe a valid design: {describe_invalid_values(exc)}.{generic}"
        ) from exc


def save_design(design: Design, path: str | os.PathLike[str], *, overwrite: bool = False) -> Path:
    """Write ``design`` to ``path`` atomically and return the path.

    Raises
    ------
    FileExistsError
        ``path`` exists and ``overwrite`` is False (nothing is written).
    """
    target = Path(path).expanduser()
    if target.is_dir():
        raise IsADirectoryError(
            errno.EISDIR, f"{target} is a folder. Fix: give a file name ending in .json", str(target)
        )
    if target.exists() and not overwrite:
        raise FileExistsError(
            errno.EEXIST,
            f"{target} already exists. Fix: pass overwrite=True to replace it, or choose another name",
            str(target),
        )
    text = design_to_json(design)  # serialise before touching the disk
    return atomic_write(target, lambda fh: fh.write(text.encode("utf-8")), overwrite=overwrite)


def load_design(path: str | os.PathLike[str]) -> Design:
    """Read a design file (see :func:`design_from_json` for the errors); a missing file or a folder
    raises ``FileNotFoundError`` naming the path and the fix."""
    target = Path(path).expanduser()
    if not target.is_file():
        problem = "is a folder, not a design file" if target.is_dir() else "does not exist"
        raise FileNotFoundError(
            f"design file {target} {problem}. Fix: check the path (relative paths start in {Path.cwd()}), "
            "or load a bundled preset with load_preset(name) (names: list_presets())."
        )
    try:
        text = target.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise DesignFileError(
            f"{target} is not a UTF-8 text file ({exc.reason}). Fix: open a .json design file."
        ) from exc
    return design_from_json(text, origin=str(target))
