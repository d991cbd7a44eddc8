"""A terminal progress bar for engine progress callbacks (tqdm)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from tqdm import tqdm

from lfm_studio.engine.progress import ProgressCallback


@contextmanager
def progress_bar(description: str, unit: str = "step") -> Iterator[ProgressCallback]:
    """Yield a ``progress(done, total, message)`` callback that drives a tqdm bar on stderr.

    ``unit`` names what ``done`` counts; a ``total`` of 0 or less means "unknown" (the bar
    then counts without a percentage instead of being reset at every call).
    """
    bar = tqdm(total=1, desc=description, unit=unit, leave=True, dynamic_ncols=True)

    def update(done: int, total: int, message: str) -> None:
        known = total if total > 0 else None
        if bar.total != known:
            bar.reset(total=known)
        bar.n = done
        bar.set_postfix_str(message, refresh=False)
        bar.refresh()

    try:
        yield update
    finally:
        bar.close()
