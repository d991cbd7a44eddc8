"""A small LRU cache of propagation transfer functions with a byte budget.

Building a transfer function costs most of one propagation (a 2048^2 ASM kernel is
about 70% of the work, docs/platform.md), and depth sweeps reuse the same few kernels.
Entries are keyed by exactly the inputs they depend on (:class:`KernelKey`), so a
change of any of them is a miss, never a stale hit. Values are tensors or tuples of
tensors that nobody modifies in place; a hit returns the very same objects.

The module holds one shared cache (:func:`default_cache`, budget 1 GiB); :func:`clear`
empties it. The cache is thread safe (GUI workers may propagate concurrently).
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from dataclasses import dataclass

import torch

Kernel = torch.Tensor | tuple[torch.Tensor, ...]

DEFAULT_BUDGET_BYTES = 1 << 30  # 1 GiB: one 8192^2 complex128 kernel, or sixteen 2048^2 ones


@dataclass(frozen=True)
class KernelKey:
    """Everything a transfer function depends on (lengths in metres, wavelength in vacuum).

    ``shape`` is the unpadded field shape and ``padded_shape`` the shape the kernel is
    built on; ``options`` holds method flags (e.g. the constant phase ``exp(j k z)``).
    """

    method: str
    shape: tuple[int, int]
    padded_shape: tuple[int, int]
    spacing: tuple[float, float]
    wavelength: float
    refractive_index: float
    distance: float
    device: str
    dtype: torch.dtype
    options: tuple = ()


def kernel_nbytes(value: Kernel) -> int:
    """Bytes of the tensors of ``value``."""
    tensors = value if isinstance(value, tuple) else (value,)
    return sum(t.numel() * t.element_size() for t in tensors)


class KernelCache:
    """LRU cache of kernels bounded by ``budget_bytes``.

    Parameters
    ----------
    budget_bytes : int
        Most bytes held; least recently used entries are evicted first. An entry
        larger than the whole budget is returned but not stored.

    Attributes
    ----------
    hits, misses : int
        Lookup counters (since construction or the last :meth:`clear`).
    """

    def __init__(self, budget_bytes: int = DEFAULT_BUDGET_BYTES) -> None:
        if int(budget_bytes) < 0:
            raise ValueError(f"budget_bytes must be >= 0 bytes; got {budget_bytes!r}. Fix: use e.g. 1 << 30.")
        self.budget_bytes = int(budget_bytes)
        self.hits = 0
        self.misses = 0
        self._entries: OrderedDict[Hashable, Kernel] = OrderedDict()
        self._nbytes = 0
        self._lock = threading.Lock()

    @property
    def nbytes(self) -> int:
        """Bytes currently held."""
        return self._nbytes

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._entries

    def get(self, key: Hashable) -> Kernel | None:
        """The cached kernel for ``key`` (counted as a hit) or ``None`` (a miss)."""
        with self._lock:
            value = self._entries.get(key)
            if value is None:
                self.misses += 1
                return None
            self._entries.move_to_end(key)
            self.hits += 1
            return value

    def put(self, key: Hashable, value: Kernel) -> bool:
        """Store ``value`` under ``key``, evicting least recently used entries to fit the budget.

        Only entries :meth:`_evictable` allows are evicted (all of them here); returns False,
        storing nothing and evicting nothing, when ``value`` cannot be made to fit.
        """
        size = kernel_nbytes(value)
        with self._lock:
            old = self._entries.pop(key, None)
            if old is not None:
                self._nbytes -= kernel_nbytes(old)
            if size > self.budget_bytes:
                return False
            victims: list[Hashable] = []
            held = self._nbytes
            for candidate, kept in self._entries.items():  # least recently used first
                if held + size <= self.budget_bytes:
                    break
                if self._evictable(candidate):
                    victims.append(candidate)
                    held -= kernel_nbytes(kept)
            if held + size > self.budget_bytes:
                return False
            for victim in victims:
                del self._entries[victim]
            self._entries[key] = value
            self._nbytes = held + size
            return True

    def _evictable(self, key: Hashable) -> bool:
        """Whether ``put`` may evict ``key`` to make room (called under the lock)."""
        return True

    def get_or_build(self, key: KernelKey, build: Callable[[], Kernel]) -> Kernel:
        """Cached kernel for ``key``, calling ``build()`` (outside the lock) on a miss."""
        value = self.get(key)
        if value is None:
            value = build()
            self.put(key, value)
        return value

    def clear(self) -> None:
        """Drop every entry and reset the hit/miss counters."""
        with self._lock:
            self._entries.clear()
            self._nbytes = 0
            self.hits = 0
            self.misses = 0


_DEFAULT = KernelCache()


def default_cache() -> KernelCache:
    """The process-wide cache used by :func:`~lfm_studio.engine.optics.propagation.propagate`."""
    return _DEFAULT


def clear() -> None:
    """Empty the process-wide cache (frees its memory) and reset its counters."""
    _DEFAULT.clear()
