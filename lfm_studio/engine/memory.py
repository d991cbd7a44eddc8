"""Memory checks before large allocations: refuse with the bytes needed instead of dying in the allocator.

A design with a huge sensor (``camera.pixel_count`` 100000 x 100000) would otherwise
make torch try to allocate hundreds of GB and fail deep inside the optics. Callers
estimate what they will hold (:func:`tensor_bytes`) and call :func:`require_memory`
first; the error names the bytes needed, the bytes available and the fix.
"""

from __future__ import annotations

import math
import os

import torch


class MemoryBudgetError(ValueError):
    """The computation would need more memory than the device has; raised before allocating."""


def tensor_bytes(shape: tuple[int, ...], dtype: torch.dtype) -> int:
    """Bytes of a dense tensor of ``shape`` and ``dtype``."""
    return math.prod(int(n) for n in shape) * torch.empty((), dtype=dtype).element_size()


def _meminfo_available() -> int | None:
    """``MemAvailable`` from ``/proc/meminfo`` in bytes (Linux), else None."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def available_bytes(device: torch.device | str = "cpu") -> int | None:
    """Free memory of ``device`` in bytes (CUDA: free device memory; CPU: available RAM), or None if unknown."""
    device = torch.device(device)
    if device.type == "cuda":
        free, _total = torch.cuda.mem_get_info(device)
        return int(free)
    found = _meminfo_available()
    if found is not None:
        return found
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def format_bytes(count: float) -> str:
    """``count`` bytes as ``"3.6e+11 bytes (335.3 GiB)"``."""
    return f"{count:.3g} bytes ({count / 2**30:.1f} GiB)"


def require_memory(
    needed: int, what: str, fix: str, *, device: torch.device | str = "cpu", available: int | None = None
) -> None:
    """Raise :class:`MemoryBudgetError` if ``needed`` bytes exceed the free memory of ``device``.

    Parameters
    ----------
    needed : lower bound of the bytes the computation will hold at once.
    what : what needs them, e.g. ``"the PSF stack of 9 depths on a 100000 x 100000 px sensor"``.
    fix : how to need less, e.g. ``"reduce camera.pixel_count"``.
    available : free bytes (default: measured with :func:`available_bytes`; unknown = no check).
    """
    free = available_bytes(device) if available is None else available
    if free is None or needed <= free:
        return
    raise MemoryBudgetError(
        f"{what} needs at least {format_bytes(needed)} of memory, but only {format_bytes(free)} is "
        f"available on {torch.device(device)}. Nothing was allocated. Fix: {fix}"
    )
