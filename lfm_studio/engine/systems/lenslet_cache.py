"""Per-lenslet result cache: editing one lenslet recomputes one lenslet.

Keys hash exactly what a lenslet's PSF depends on (system optics without the MLA,
the lenslet itself, depths, accuracy, device, dtype); values are the binned
``(Z, n, n)`` power patches. Least recently used entries go first past a byte budget.
"""

from __future__ import annotations

import hashlib
from collections.abc import Hashable

from lfm_studio.engine.optics.kernel_cache import KernelCache


def stable_key(*parts: Hashable) -> str:
    """A sha256 of the ``repr`` of hashable, deterministic parts (floats, tuples, strings)."""
    return hashlib.sha256(repr(parts).encode()).hexdigest()


class LensletCache(KernelCache):
    """LRU cache of per-lenslet PSF patches under a byte budget, keyed by :func:`stable_key` strings.

    The same thread-safe cache as the propagators' kernels (:class:`KernelCache`);
    ``hits`` and ``misses`` count since construction (a miss is one lenslet computed).
    """

    def __init__(self, max_bytes: int = 2 * 2**30) -> None:
        super().__init__(budget_bytes=max_bytes)
