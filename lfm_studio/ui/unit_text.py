"""Units as the studio shows them: "µm" in labels, tables and plot axes (the engine and the CLI write "um")."""

from __future__ import annotations

_SHOWN = {"um": "µm", "um^2": "µm²"}


def shown_unit(unit: str) -> str:
    """``unit`` as the studio's labels show it: ``"um"`` is ``"µm"``; other units unchanged."""
    return _SHOWN.get(unit, unit)
