"""The one accessor for bundled resources (preset designs, icons).

``resources/`` at the repository top level is installed as the package
``lfm_studio.resources``; read it through :func:`resource_path`, never by joining
paths around ``__file__``.
"""

from __future__ import annotations

from importlib import resources
from importlib.resources.abc import Traversable


def resource_path(*parts: str) -> Traversable:
    """Return a traversable handle to ``resources/<parts...>``."""
    node = resources.files("lfm_studio.resources")
    for part in parts:
        node = node.joinpath(part)
    return node


def list_resources(folder: str, suffix: str = "") -> list[str]:
    """Names of the files in ``resources/<folder>`` ending in ``suffix``, sorted."""
    node = resource_path(folder)
    if not node.is_dir():
        return []
    return sorted(p.name for p in node.iterdir() if p.is_file() and p.name.endswith(suffix))
