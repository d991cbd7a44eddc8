"""Design-file schema versions and the migrations that bring old files up to date.

A migration is registered for the version it reads and returns the data of the next
version; :func:`migrate` chains them up to :data:`SCHEMA_VERSION`. Every key a
migration removes is recorded in :data:`RETIRED_KEYS`, so an "unknown key" message
can say which schema version knew it.

Versions
--------
0 : pre-release files. As version 1, but the emission wavelength was stored in
    micrometres, top-level key ``wavelength_um``.
1 : current. Wavelength in nanometres, ``wavelength_nm``.
"""

from __future__ import annotations

from collections.abc import Callable
from decimal import Decimal
from typing import Any

from lfm_studio.engine.design.design import SCHEMA_VERSION
from lfm_studio.engine.design.errors import DesignFileError

Migration = Callable[[dict[str, Any]], dict[str, Any]]

MIGRATIONS: dict[int, Migration] = {}
"""Version read -> function returning the next version's data (a new dict; input untouched)."""

RETIRED_KEYS: dict[tuple[str, str], tuple[int, str]] = {}
"""(parent location, key) -> (last schema version that had the key, what replaced it)."""


def register_migration(
    from_version: int, *, retired: dict[str, str] | None = None
) -> Callable[[Migration], Migration]:
    """Register ``fn`` as the migration from ``from_version`` to ``from_version + 1``.

    ``retired`` maps dotted key paths the migration removes (``"wavelength_um"`` at the
    top level, ``"objective.tube_mm"`` nested) to a note on what replaced them.
    """

    def decorator(fn: Migration) -> Migration:
        if from_version in MIGRATIONS:
            raise ValueError(f"a migration from schema_version {from_version} is already registered.")
        MIGRATIONS[from_version] = fn
        for dotted, replacement in (retired or {}).items():
            parent, _, key = dotted.rpartition(".")
            RETIRED_KEYS[(parent, key)] = (from_version, replacement)
        return fn

    return decorator


def migrate(data: dict[str, Any], *, origin: str = "design") -> dict[str, Any]:
    """Bring design data of any older schema version up to :data:`SCHEMA_VERSION` (new dict)."""
    version = data["schema_version"]
    while version < SCHEMA_VERSION:
        if version not in MIGRATIONS:
            raise DesignFileError(
                f"{origin}: no migration from schema_version {version}; this lfm_studio reads versions "
                f"{min(MIGRATIONS, default=SCHEMA_VERSION)}-{SCHEMA_VERSION}. Fix: re-create the design."
            )
        data = MIGRATIONS[version](dict(data))
        version += 1
        data["schema_version"] = version
    return data


@register_migration(0, retired={"wavelength_um": "wavelength_nm (nanometres) since schema_version 1"})
def _v0_to_v1(data: dict[str, Any]) -> dict[str, Any]:
    """Version 0 stored the wavelength in micrometres as ``wavelength_um``."""
    if "wavelength_um" in data:
        if "wavelength_nm" in data:
            raise DesignFileError(
                "a schema_version 0 design must not hold both wavelength_um and wavelength_nm. Fix: keep one."
            )
        value = data.pop("wavelength_um")
        # Exact decimal scaling: 0.525 um -> 525.0 nm, not 525.0000000000001.
        data["wavelength_nm"] = (
            float(Decimal(repr(value)).scaleb(3))
            if isinstance(value, (int, float)) and not isinstance(value, bool)
            else value
        )
    return data
