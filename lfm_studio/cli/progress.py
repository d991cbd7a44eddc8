"""A terminal progress bar for engine progress callbacks (tqdm)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from tqdm import tqdm

from lfm_studio.engine.progress import ProgressCallback


@contextmanager
def progress_bar(description: str) -> Iterator[ProgressCallback]:
    """Yield a ``progress(done, total, message)`` callback that drives a tqdm bar on stderr."""
    bar = tqdm(total=1, desc=description, unit="step", leave=True, dynamic_ncols=True)

    def update(done: int, total: int, message: str) -> None:
        if bar.total != total:
            bar.reset(total=max(total, 1))
        bar.n = done
        bar.set_postfix_str(message, refresh=False)
        bar.refresh()

    try:
        yield update
    finally:
        bar.close()
