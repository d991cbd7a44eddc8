"""Random non-overlapping placement (random sequential addition with a spatial hash).

Each candidate has a centre ``p`` and a relative size ``s`` in ``(0, 1]``; in the
*normalised* space ``q = p / scale`` (``scale`` per axis) two objects conflict when
``|q_i - q_j| < (s_i + s_j) / 2``, so aligned ellipsoids of semi-axes ``s scale / 2``
never overlap. Candidates are drawn in batches and accepted when they conflict with
no accepted object. Neighbours are found through cells of side
``0.99 min(s) / sqrt(3)``, which hold at most one centre each, so a candidate looks at
a fixed set of nearby cells (125 for equal sizes) and no pair loop or volume-sized
grid is ever formed; everything is vectorised per batch.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

_DENSE_LIMIT = 1 << 24  # cell-index tables up to 64 MB are dense, larger ones sorted


class PlacementError(ValueError):
    """The requested objects do not fit (too many, too large, too far apart)."""


class _CellIndex:
    """Map from cell key to the id of the centre in it (``-1``: empty); dense or sorted."""

    def __init__(self, size: int):
        self.dense = size <= _DENSE_LIMIT
        self.table = torch.full((size if self.dense else 0,), -1, dtype=torch.int64)
        self.keys = torch.zeros(0, dtype=torch.int64)
        self.ids = torch.zeros(0, dtype=torch.int64)

    def lookup(self, keys: torch.Tensor) -> torch.Tensor:
        if self.dense:
            return self.table[keys]
        if len(self.keys) == 0:
            return torch.full_like(keys, -1)
        slot = torch.searchsorted(self.keys, keys).clamp_(max=len(self.keys) - 1)
        return torch.where(self.keys[slot] == keys, self.ids[slot], -1)

    def insert(self, keys: torch.Tensor, ids: torch.Tensor) -> None:
        if self.dense:
            self.table[keys] = ids
            return
        self.keys, order = torch.sort(torch.cat([self.keys, keys]))
        self.ids = torch.cat([self.ids, ids])[order]

    def remove(self, keys: torch.Tensor) -> None:
        if self.dense:
            self.table[keys] = -1
            return
        keep = ~torch.isin(self.keys, keys)
        self.keys, self.ids = self.keys[keep], self.ids[keep]


def place_separated(
    count: int,
    sample: Callable[[int], tuple[torch.Tensor, torch.Tensor]],
    *,
    low: torch.Tensor,
    high: torch.Tensor,
    scale: torch.Tensor | None,
    min_size: float = 1.0,
    max_draws: int | None = None,
    allow_fewer: bool = False,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``count`` non-conflicting objects drawn by ``sample``: centres ``(count, 3)`` and sizes ``(count,)``.

    Parameters
    ----------
    sample : ``sample(n)`` returns up to ``n`` candidates: centres ``(m, 3)`` float64 in metres,
        all inside the box ``[low, high]``, and sizes ``(m,)`` in ``[min_size, 1]``; it owns
        the random generator.
    low, high : ``(3,)`` float64 bounding box of the candidates, metres.
    scale : ``(3,)`` float64 centre distance per axis (metres) of two size-1 objects that
        touch, or ``None`` for no check (objects may then overlap).
    min_size : the smallest size ``sample`` returns (sets the cell side).
    max_draws : give up after this many candidates (default ``30 * count + 100_000``), or as
        soon as the last batch's acceptance rate says the rest cannot fit in that budget
        (acceptance only falls as the volume fills, so this never gives up too early).
    allow_fewer : return the objects placed so far instead of raising :class:`PlacementError`
        when no more fit (the caller then has fewer than ``count`` and should say so).
    """
    found = torch.zeros((0, 3), dtype=torch.float64)
    sizes = torch.zeros(0, dtype=torch.float64)
    limit = max_draws if max_draws is not None else 30 * count + 100_000
    if scale is None:
        while len(found) < count:
            more, more_sizes = sample(count - len(found))
            found, sizes = torch.cat([found, more]), torch.cat([sizes, more_sizes])
        return found[:count], sizes[:count]
    if not 0 < min_size <= 1:
        raise ValueError(f"min_size must be in (0, 1]; got {min_size!r}.")
    cell = 0.99 * min_size / math.sqrt(3.0)  # diagonal < min_size: one centre per cell at most
    reach = math.ceil(1.0 / cell)  # conflicting centres (distance < 1) are this many cells apart at most
    dims = [int(n) + 1 + 2 * reach for n in torch.floor((high - low) / scale / cell)]
    strides = torch.tensor([dims[1] * dims[2], dims[2], 1], dtype=torch.int64)
    span = torch.arange(-reach, reach + 1)
    steps = torch.cartesian_prod(span, span, span)
    gap = (steps.abs() - 1).clamp_min(0).to(torch.float64) * cell  # closest approach of two cells
    offsets = (steps[(gap**2).sum(-1) < 1.0] * strides).sum(-1)  # key steps of cells within reach
    max_batch = max(1024, (1 << 22) // len(offsets))  # bounds the (batch, neighbours) lookups
    index = _CellIndex(math.prod(dims))
    origin = low / scale
    accepted_q = torch.zeros((0, 3), dtype=torch.float64)
    drawn, rate = 0, 1.0
    while len(found) < count:
        if drawn >= limit or (count - len(found)) > rate * (limit - drawn):
            if allow_fewer:
                break
            raise PlacementError(
                f"could place only {len(found)} of {count} non-overlapping objects after {drawn} random "
                f"tries (the last batch accepted {rate:.2%}; random packing stalls near 30 % of the volume "
                "filled by the exclusion spheres). Fix: ask for fewer or smaller objects, a smaller "
                "separation, or a larger volume."
            )
        # Size the batch from the last acceptance rate, so the end game takes few rounds.
        batch = min(
            max(math.ceil(1.2 * (count - len(found)) / max(rate, 1e-3)), 1024), max_batch, limit - drawn
        )
        candidates, size = sample(batch)
        drawn += batch
        q = candidates / scale
        keys = ((torch.floor((q - origin) / cell).to(torch.int64) + reach) * strides).sum(-1)
        # Drop candidates in an occupied cell, then keep the first candidate of each cell.
        free = index.lookup(keys) < 0
        candidates, size, q, keys = candidates[free], size[free], q[free], keys[free]
        sorted_keys, perm = torch.sort(keys, stable=True)
        first = torch.ones(len(keys), dtype=torch.bool)
        first[1:] = sorted_keys[1:] != sorted_keys[:-1]
        rep = torch.sort(perm[first]).values  # batch order
        candidates, size, q, keys = candidates[rep], size[rep], q[rep], keys[rep]
        # Insert the batch with ids after the accepted ones; a candidate conflicts with any
        # accepted centre, or with an earlier batch candidate, closer than 1 (conservative).
        m = len(found)
        own = torch.arange(m, m + len(keys))
        index.insert(keys, own)
        ref_q, ref_size = torch.cat([accepted_q, q]), torch.cat([sizes, size])
        neighbour_ids = index.lookup(keys[:, None] + offsets[None, :])
        rows, cols = torch.nonzero(neighbour_ids >= 0, as_tuple=True)
        other = neighbour_ids[rows, cols]
        touch = (size[rows] + ref_size[other]) / 2
        close = (((q[rows] - ref_q[other]) ** 2).sum(-1) < touch**2) & (other < own[rows])
        clash = torch.zeros(len(keys), dtype=torch.bool)
        clash[rows[close]] = True
        keep = (~clash).nonzero().squeeze(1)[: count - m]
        index.remove(keys)
        index.insert(keys[keep], torch.arange(m, m + len(keep)))
        found, sizes = torch.cat([found, candidates[keep]]), torch.cat([sizes, size[keep]])
        rate = len(keep) / batch
        accepted_q = torch.cat([accepted_q, q[keep]])
    return found, sizes
