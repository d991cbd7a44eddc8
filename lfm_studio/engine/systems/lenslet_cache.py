"""Per-lenslet result cache: editing one lenslet recomputes one lenslet.

Keys hash the spec objects a lenslet's PSF depends on (:func:`spec_key`: every field of
the dataclasses, recursively, never a hand-written list, so a field added later is in
the key automatically); values are the binned ``(Z, n, n)`` power patches. Least
recently used entries go first past a byte budget.
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections.abc import Hashable, Mapping

import torch

from lfm_studio.engine.optics.kernel_cache import KernelCache


def stable_key(*parts: Hashable) -> str:
    """A sha256 of the ``repr`` of hashable, deterministic parts (floats, tuples, strings)."""
    return hashlib.sha256(repr(parts).encode()).hexdigest()


def spec_parts(obj: object, *, exclude: tuple[str, ...] = ()) -> Hashable:
    """A deterministic, hashable description of ``obj`` built from its own fields.

    Dataclasses become ``(type name, ((field, value), ...))`` over *all* their fields
    (minus the top-level names in ``exclude``), pydantic models their ``model_dump``,
    tensors their dtype, shape and values (detached), sequences and mappings their
    items; floats keep their exact ``repr``. Anything else raises ``TypeError`` rather
    than being keyed by an address or left out.
    """
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        items = tuple(
            (f.name, spec_parts(getattr(obj, f.name)))
            for f in dataclasses.fields(obj)
            if f.name not in exclude
        )
        return (type(obj).__qualname__, items)
    model_dump = getattr(obj, "model_dump", None)
    if callable(model_dump):
        dumped = model_dump()
        return (type(obj).__qualname__, spec_parts({k: v for k, v in dumped.items() if k not in exclude}))
    if isinstance(obj, torch.Tensor):
        values = obj.detach().cpu().reshape(-1).tolist()
        return ("tensor", str(obj.dtype), tuple(obj.shape), tuple(values))
    if isinstance(obj, torch.dtype | torch.device):
        return str(obj)
    if obj is None or isinstance(obj, bool | int | float | str):
        return obj
    if isinstance(obj, Mapping):
        return tuple(sorted((str(k), spec_parts(v)) for k, v in obj.items()))
    if isinstance(obj, tuple | list):
        return tuple(spec_parts(v) for v in obj)
    raise TypeError(
        f"cannot derive a cache key from a {type(obj).__name__}; give it dataclass fields or "
        "teach spec_parts its value."
    )


def spec_key(*objs: object) -> str:
    """:func:`stable_key` of :func:`spec_parts` of each object."""
    return stable_key(*(spec_parts(obj) for obj in objs))


class LensletCache(KernelCache):
    """LRU cache of per-lenslet PSF patches under a byte budget, keyed by :func:`stable_key` strings.

    The same thread-safe cache as the propagators' kernels (:class:`KernelCache`);
    ``hits`` and ``misses`` count since construction (a miss is one lenslet computed).
    """

    def __init__(self, max_bytes: int = 2 * 2**30) -> None:
        super().__init__(budget_bytes=max_bytes)
