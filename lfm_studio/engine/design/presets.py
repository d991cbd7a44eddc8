"""Bundled preset designs (``resources/designs/*.json``), read through :mod:`lfm_studio.resources_access`."""

from __future__ import annotations

import os
from pathlib import Path

from lfm_studio.engine.design.design import Design
from lfm_studio.engine.design.design_io import design_from_json, load_design
from lfm_studio.engine.design.errors import DesignFileError
from lfm_studio.resources_access import list_resources, resource_path

PRESET_FOLDER = "designs"


def list_presets() -> list[str]:
    """Names of the bundled presets (file names without ``.json``), sorted."""
    return [name.removesuffix(".json") for name in list_resources(PRESET_FOLDER, ".json")]


def load_preset(name: str) -> Design:
    """The bundled preset ``name`` (see :func:`list_presets`)."""
    available = list_presets()
    if name not in available:
        raise DesignFileError(f"no preset named {name!r}; available: {', '.join(available)}.")
    text = resource_path(PRESET_FOLDER, f"{name}.json").read_text(encoding="utf-8")
    return design_from_json(text, origin=f"preset {name!r}")


def resolve_design(name_or_path: str | os.PathLike[str], option: str = "design") -> Design:
    """A design from a preset name or a file path (what the command line accepts).

    A path-like object, or a string that ends in ``.json`` or contains a path
    separator, is read as a file; otherwise a preset name is tried first, then a
    file of that name. A missing file raises ``FileNotFoundError`` naming ``option``
    (``"--design"`` where the command line takes it as an option), the path and a fix.
    """
    text = os.fspath(name_or_path)
    looks_like_path = (
        not isinstance(name_or_path, str)
        or text.endswith(".json")
        or any(sep and sep in text for sep in (os.sep, os.altsep))
    )
    if not looks_like_path:
        if text in list_presets():
            return load_preset(text)
        if not Path(text).is_file():
            raise DesignFileError(
                f"{text!r} is neither a preset ({', '.join(list_presets())}) nor an existing design file. "
                "Fix: check the spelling, or give the path to a .json design file."
            )
    target = Path(text).expanduser()
    if not target.is_file():
        problem = "a folder, not a design file" if target.is_dir() else "no such design file"
        raise FileNotFoundError(
            f"{option} {text}: {problem}. Fix: give the path to a .json design file, or a preset name "
            f"({', '.join(list_presets())})."
        )
    return load_design(text)
