"""Per-lenslet result cache: editing one lenslet recomputes one lenslet.

Keys hash the spec objects a lenslet's PSF depends on (:func:`spec_key`: every field of
the dataclasses, recursively, never a hand-written list, so a field added later is in
the key automatically); values are the binned power patches cut to the sensor (a
lenslet whose light misses a cropped sensor is skipped before the cache is asked, and
never stored). Past a byte budget
(default: a quarter of free memory, :func:`default_cache_bytes`) least recently used
entries go first, but never those of the PSF stack being computed (:class:`LensletCache`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import warnings
from collections.abc import Hashable, Iterator, Mapping
from contextlib import contextmanager

import torch

from lfm_studio.engine.memory import available_bytes, format_bytes
from lfm_studio.engine.optics.kernel_cache import Kernel, KernelCache, kernel_nbytes


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


class LensletCacheWarning(UserWarning):
    """The per-lenslet cache is smaller than one design's lenslets: some are recomputed every time."""


# Default budget: a quarter of the free memory of the device, within these bounds (a
# 2048 px XLFM at 101 depths holds about 0.7 GiB of lenslet patches on the whole sensor).
DEFAULT_MIN_BYTES = 512 * 2**20
DEFAULT_MAX_BYTES = 8 * 2**30
UNKNOWN_MEMORY_BYTES = 2 * 2**30


def default_cache_bytes(device: torch.device | str = "cpu") -> int:
    """Budget of a lenslet cache on ``device``: a quarter of its free memory
    (:func:`~lfm_studio.engine.memory.available_bytes`), clamped to
    [:data:`DEFAULT_MIN_BYTES`, :data:`DEFAULT_MAX_BYTES`]; :data:`UNKNOWN_MEMORY_BYTES` when
    the free memory is unknown."""
    free = available_bytes(device)
    if free is None:
        return UNKNOWN_MEMORY_BYTES
    return int(min(DEFAULT_MAX_BYTES, max(DEFAULT_MIN_BYTES, free // 4)))


class LensletCache(KernelCache):
    """Cache of per-lenslet PSF patches under a byte budget, keyed by :func:`stable_key` strings.

    The same thread-safe cache as the propagators' kernels (:class:`KernelCache`), with a
    policy that does not thrash: a PSF stack opens a *round* (:meth:`begin_round`), and the
    entries it uses or stores are not evicted for the rest of that round. Least recently used
    entries of earlier rounds go first; when only the current round's entries are left, a new
    patch is returned but not stored (``not_stored``). So a budget smaller than one design's
    lenslets keeps what fits, and a repeated candidate hits on those, instead of every miss
    evicting the entry needed next (plain LRU over a cyclic scan: zero hits).

    Attributes
    ----------
    hits, misses : lookups since construction (a miss is one lenslet computed).
    not_stored : patches computed but not stored because the current round's entries fill the budget.
    round_bytes : bytes of the patches the current (or last) round used or stored (for a round
        abandoned by an error, those it used before it stopped).
    warned : whether the "smaller than one design" :class:`LensletCacheWarning` was given (once per cache).

    A PSF stack runs in :meth:`stack_round`, which closes its round whatever happens.
    """

    def __init__(self, max_bytes: int | None = None, *, device: torch.device | str = "cpu") -> None:
        super().__init__(budget_bytes=default_cache_bytes(device) if max_bytes is None else max_bytes)
        self._round = 0
        self._last_used: dict[Hashable, int] = {}
        self.not_stored = 0
        self.round_bytes = 0
        self._round_not_stored = 0
        self.warned = False

    def begin_round(self) -> None:
        """Start a new round (one PSF stack): entries of earlier rounds become evictable."""
        with self._lock:
            self._round += 1
            self.round_bytes = 0
            self._round_not_stored = 0

    @contextmanager
    def stack_round(self) -> Iterator[None]:
        """One PSF stack's round: :meth:`begin_round`, then :meth:`end_round` when the body returns.

        When the body raises (a cancel, a refused lenslet), the round is abandoned instead: no
        warning (a partial stack's patches say nothing of the budget a design needs), its
        not-stored count is dropped, and its entries are no longer protected from eviction (the
        stack they were kept for is gone). A round that a later :meth:`begin_round` already
        replaced (another thread's stack) is left alone. The exception propagates."""
        self.begin_round()
        with self._lock:
            number = self._round
        try:
            yield
        except BaseException:
            with self._lock:
                if self._round == number:
                    self._round_not_stored = 0
                    self._round += 1
            raise
        self.end_round(stacklevel=5)  # through contextlib: the warning names the stack's caller

    def end_round(self, *, stacklevel: int = 3) -> None:
        """Close the round; warns once per cache (:class:`LensletCacheWarning`) if patches did not fit
        (``stacklevel`` as for :func:`warnings.warn`, counted from here)."""
        if self._round_not_stored and not self.warned:
            self.warned = True
            warnings.warn(
                f"The lenslet cache ({format_bytes(self.budget_bytes)}) is smaller than one design's "
                f"lenslet patches ({format_bytes(self.round_bytes)}): {self._round_not_stored} lenslet(s) "
                "were not stored and are recomputed for every candidate (the stored ones still hit). "
                f"Fix: give the cache at least {format_bytes(self.round_bytes)} (e.g. Evaluator(cache_bytes=...)), "
                "crop the sensor or simulate fewer depths.",
                LensletCacheWarning,
                stacklevel=stacklevel,
            )

    def get(self, key: Hashable) -> Kernel | None:
        value = super().get(key)
        if value is not None:
            with self._lock:
                self._mark(key, value)
        return value

    def put(self, key: Hashable, value: Kernel) -> bool:
        stored = super().put(key, value)
        with self._lock:
            if stored:
                self._mark(key, value)
            else:
                self._last_used.pop(key, None)
                self.round_bytes += kernel_nbytes(value)
                self.not_stored += 1
                self._round_not_stored += 1
            for gone in [k for k in self._last_used if k not in self._entries]:
                del self._last_used[gone]
        return stored

    def counters(self) -> tuple[int, int, int]:
        """``(hits, misses, not_stored)`` now, for :meth:`use_since`."""
        return self.hits, self.misses, self.not_stored

    def use_since(self, before: tuple[int, int, int]) -> dict[str, int]:
        """Cache use since :meth:`counters` returned ``before``: ``hits`` and ``misses``, plus, when
        patches did not fit, ``not_stored``, ``needed_bytes`` (the last round's patches) and
        ``budget_bytes``."""
        use = {"hits": self.hits - before[0], "misses": self.misses - before[1]}
        if self.not_stored > before[2]:
            use.update(
                not_stored=self.not_stored - before[2],
                needed_bytes=self.round_bytes,
                budget_bytes=self.budget_bytes,
            )
        return use

    def stats(self) -> dict[str, int]:
        """Counters and sizes: hits, misses, not_stored, held_bytes, budget_bytes, round_bytes."""
        return {
            "hits": self.hits,
            "misses": self.misses,
            "not_stored": self.not_stored,
            "held_bytes": self.nbytes,
            "budget_bytes": self.budget_bytes,
            "round_bytes": self.round_bytes,
        }

    def clear(self) -> None:
        super().clear()
        with self._lock:
            self._last_used.clear()
            self.not_stored = 0
            self.round_bytes = 0
            self._round_not_stored = 0

    def _mark(self, key: Hashable, value: Kernel) -> None:
        if self._last_used.get(key) != self._round:
            self.round_bytes += kernel_nbytes(value)
        self._last_used[key] = self._round

    def _evictable(self, key: Hashable) -> bool:
        return self._last_used.get(key) != self._round
