"""Per-lenslet result cache: editing one lenslet recomputes one lenslet.

Keys hash exactly what a lenslet's PSF depends on (system optics without the MLA,
the lenslet itself, depths, accuracy, device, dtype); values are the binned
``(Z, n, n)`` power patches. Least recently used entries go first past a byte budget.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from collections.abc import Hashable

import torch


def stable_key(*parts: Hashable) -> str:
    """A sha256 of the ``repr`` of hashable, deterministic parts (floats, tuples, strings)."""
    return hashlib.sha256(repr(parts).encode()).hexdigest()


class LensletCache:
    """LRU cache of per-lenslet PSF patches with a byte budget.

    Attributes
    ----------
    hits, misses : counters since construction (a miss is one lenslet computed).
    """

    def __init__(self, max_bytes: int = 2 * 2**30) -> None:
        self.max_bytes = int(max_bytes)
        self._entries: OrderedDict[str, torch.Tensor] = OrderedDict()
        self._bytes = 0
        self.hits = 0
        self.misses = 0

    def __len__(self) -> int:
        return len(self._entries)

    def get(self, key: str) -> torch.Tensor | None:
        value = self._entries.get(key)
        if value is None:
            self.misses += 1
            return None
        self._entries.move_to_end(key)
        self.hits += 1
        return value

    def put(self, key: str, value: torch.Tensor) -> None:
        size = value.element_size() * value.numel()
        if size > self.max_bytes:
            return
        if key in self._entries:
            old = self._entries.pop(key)
            self._bytes -= old.element_size() * old.numel()
        self._entries[key] = value
        self._bytes += size
        while self._bytes > self.max_bytes:
            _, old = self._entries.popitem(last=False)
            self._bytes -= old.element_size() * old.numel()

    def clear(self) -> None:
        self._entries.clear()
        self._bytes = 0
