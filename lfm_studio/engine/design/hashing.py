"""Stable content hashes of specs, for caching pipeline stages.

``spec_hash(spec)`` is the SHA-256 hex digest of the spec's canonical JSON:
``{"spec": <class name>, "fields": <model_dump(mode="json")>}`` written with sorted
keys, no whitespace, ASCII only, and ``-0.0`` written as ``0.0``. It depends only on
the values (not on the process, the Python hash seed or the field order), so a
stage can key its cache on exactly the sub-spec it reads: ``spec_hash(design.mla)``
changes when the MLA changes and not when the camera noise does.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable
from typing import Any

from pydantic import BaseModel

from lfm_studio.engine.design.design import METADATA_FIELDS, Design


def _normalise(value: Any) -> Any:
    if isinstance(value, float) and value == 0.0:
        return 0.0
    if isinstance(value, dict):
        return {k: _normalise(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_normalise(v) for v in value]
    return value


def canonical_json(spec: BaseModel, *, exclude: Iterable[str] = ()) -> str:
    """The canonical JSON text that :func:`spec_hash` digests (top-level ``exclude`` fields left out)."""
    fields = _normalise(spec.model_dump(mode="json", exclude=set(exclude) or None))
    payload = {"spec": type(spec).__name__, "fields": fields}
    return json.dumps(payload, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def spec_hash(spec: BaseModel, *, exclude: Iterable[str] = ()) -> str:
    """SHA-256 hex digest (64 characters) of ``canonical_json(spec, exclude=exclude)``."""
    return hashlib.sha256(canonical_json(spec, exclude=exclude).encode("ascii")).hexdigest()


def optics_hash(design: Design) -> str:
    """Hash of a design without its descriptive fields (name, description, source, assumed)."""
    return spec_hash(design, exclude=METADATA_FIELDS)


def lenslet_hashes(mla: Any) -> tuple[str, ...]:
    """One :func:`spec_hash` per lenslet of ``mla`` (either MLA form), in lenslet order.

    Moving one lenslet changes its hash only: a Fourier-LFM stage that computes
    sub-images per lenslet recomputes just that one.
    """
    return tuple(spec_hash(lens) for lens in mla.lenslets)
