"""FFT-friendly sizes: the smallest 2-3-5-smooth integer at or above a length."""

from __future__ import annotations

from functools import lru_cache


@lru_cache(maxsize=4096)
def next_fast_length(n: int) -> int:
    """Smallest integer ``>= n`` whose only prime factors are 2, 3 and 5."""
    if n < 1:
        raise ValueError(f"FFT length must be >= 1; got {n}.")
    candidate = n
    while True:
        m = candidate
        for p in (2, 3, 5):
            while m % p == 0:
                m //= p
        if m == 1:
            return candidate
        candidate += 1
