"""Pairing of real and complex torch dtypes (float32 <-> complex64, float64 <-> complex128)."""

from __future__ import annotations

import torch

_COMPLEX_OF = {torch.float32: torch.complex64, torch.float64: torch.complex128}
_REAL_OF = {torch.complex64: torch.float32, torch.complex128: torch.float64}


def complex_dtype(dtype: torch.dtype) -> torch.dtype:
    """The complex dtype matching ``dtype`` (real or complex); float32/64 only."""
    if dtype in _REAL_OF:
        return dtype
    if dtype not in _COMPLEX_OF:
        raise ValueError(
            f"dtype must be float32, float64, complex64 or complex128; got {dtype}. "
            "Fix: use torch.complex64 for speed or torch.complex128 for reference accuracy."
        )
    return _COMPLEX_OF[dtype]


def real_dtype(dtype: torch.dtype) -> torch.dtype:
    """The real dtype matching ``dtype`` (real or complex); float32/64 only."""
    if dtype in _COMPLEX_OF:
        return dtype
    if dtype not in _REAL_OF:
        raise ValueError(
            f"dtype must be float32, float64, complex64 or complex128; got {dtype}. "
            "Fix: use torch.float32 for speed or torch.float64 for reference accuracy."
        )
    return _REAL_OF[dtype]


_BY_NAME = {"float32": torch.float32, "float64": torch.float64}


def real_dtype_named(name: str | torch.dtype) -> torch.dtype:
    """``torch.float32`` or ``torch.float64`` from the name used in design files and the CLI
    (``"float32"``, ``"float64"``), or that torch dtype itself."""
    if isinstance(name, torch.dtype) and name in _BY_NAME.values():
        return name
    if not isinstance(name, str) or name not in _BY_NAME:
        raise ValueError(
            f"dtype must be 'float32' or 'float64' (or torch.float32 / torch.float64); got {name!r}. "
            "Fix: 'float32' for speed, 'float64' for reference accuracy."
        )
    return _BY_NAME[name]
