"""Keep large freed blocks in the process heap (glibc), so per-depth FFT buffers are not page-faulted in again.

The projectors allocate and free tens-of-megabyte spectra for every depth. glibc serves
blocks above its mmap threshold with ``mmap`` and returns them with ``munmap`` (and trims
the heap top above its trim threshold), so every depth touches fresh pages: measured
128,000 minor page faults for 3 forward + back projections of the XLFM preset at
2048^2 x 8 depths, 5,600 with :func:`keep_freed_memory`, and 1.65x faster projections on
the busy 2-core machine (``benchmarks/projector_versions.py``). The cost: up to
``TRIM_THRESHOLD`` bytes of freed heap stay mapped to the process.

One malloc arena for every thread (``M_ARENA_MAX`` 1): glibc gives each new thread an arena of its
own, and with the raised thresholds each arena keeps its own freed blocks, so the worker threads of
:func:`lfm_studio.engine.threads.run_in_workers` each held their temporaries twice over (the
conventional build's peak with 2 workers: 560-621 MiB, 545-563 MiB with ``MALLOC_ARENA_MAX=1``).
The engine's allocations are few and large, so one arena's lock costs nothing measurable.

Process-wide: ``lfm_studio.cli.commands.main`` calls it at start-up for every command (``gui`` included),
and the benchmarks do; the engine never calls it on import.
"""

from __future__ import annotations

import ctypes
import ctypes.util

MMAP_THRESHOLD = 32 * 2**20  # glibc's upper limit for M_MMAP_THRESHOLD on 64-bit systems
TRIM_THRESHOLD = 512 * 2**20  # freed heap kept before it is returned to the system
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_ARENA_MAX = -1, -3, -8  # <malloc.h>
ARENAS = 1  # malloc arenas shared by all threads


def keep_freed_memory() -> bool:
    """Raise glibc's mmap and trim thresholds and share one arena between threads (``mallopt``);
    ``False`` where there is no glibc."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc (musl, macOS, Windows)
        return False
    settings = (
        (_M_MMAP_THRESHOLD, MMAP_THRESHOLD),
        (_M_TRIM_THRESHOLD, TRIM_THRESHOLD),
        (_M_ARENA_MAX, ARENAS),
    )
    return all(bool(mallopt(option, value)) for option, value in settings)
