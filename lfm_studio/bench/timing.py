"""Wall-clock timing with interleaved repeats (the machines are shared: compare ratios).

Each round runs every setting once, in order, so a slow spell from another process
hits all settings alike; a setting's time is its fastest round. Settings slower than
``single_run_above`` seconds in the first round are not repeated.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import TypeVar

T = TypeVar("T")


def interleaved_times(
    tasks: Sequence[Callable[[], T]],
    *,
    repeats: int,
    single_run_above: float = 20.0,
    first: Callable[[int, T], None] | None = None,
    before: Callable[[int, int], None] | None = None,
) -> list[float]:
    """Fastest wall time (s) of each task over ``repeats`` interleaved rounds.

    Parameters
    ----------
    tasks : zero-argument callables.
    repeats : rounds (>= 1).
    single_run_above : tasks slower than this (s) in round one run only once.
    first : called with (index, result) after each task's first run (e.g. to measure its error).
    before : called with (index, round) before each run (progress).
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1; got {repeats}.")
    best = [float("inf")] * len(tasks)
    for round_ in range(repeats):
        for i, task in enumerate(tasks):
            if round_ > 0 and best[i] > single_run_above:
                continue
            if before is not None:
                before(i, round_)
            start = time.perf_counter()
            result = task()
            best[i] = min(best[i], time.perf_counter() - start)
            if round_ == 0 and first is not None:
                first(i, result)
            del result
    return best
