"""Exceptions and warnings raised by the engine, and the checks that raise them.

Every message names the parameter, the value it got (with its unit), the limit
and a fix, so a user can correct a design without reading the source.
"""

from __future__ import annotations

import math
import os
import sys
import warnings
from collections.abc import Sequence
from types import FrameType

import torch
from pydantic import ValidationError

_ENGINE_DIR = os.path.dirname(os.path.abspath(__file__))


class SamplingWarning(UserWarning):
    """A sampling criterion is violated; the result may be aliased or inaccurate."""


class SamplingError(ValueError):
    """A computation cannot be sampled on the given grid; raised before heavy work."""


def listed(values: Sequence[float], scale: float = 1.0, unit: str = "", most: int = 5) -> str:
    """``values / scale`` for a message, as ``"a, b, c"``, each followed by ``unit`` (e.g.
    ``" * um"`` for a fix), at most ``most`` of them, then ``...``."""
    shown = ", ".join(f"{v / scale:g}{unit}" for v in values[:most])
    return shown + (", ..." if len(values) > most else "")


def require_positive(name: str, value: float | torch.Tensor, unit: str, fix: str = "") -> None:
    """Raise ``ValueError`` unless ``value`` is a finite number > 0.

    Parameters
    ----------
    name : parameter name as the caller knows it (e.g. ``"wavelength"``).
    value : the value to check; a 0-d tensor is accepted (trainable parameters).
    unit : unit of ``value`` as written in the message (e.g. ``"m"``).
    fix : a hint appended to the message.
    """
    number = float(value.detach()) if isinstance(value, torch.Tensor) else float(value)
    if not (math.isfinite(number) and number > 0.0):
        hint = f" Fix: {fix}" if fix else ""
        raise ValueError(f"{name} must be a finite number > 0 {unit}; got {number:.6g} {unit}.{hint}")


def require_finite(name: str, value: float | torch.Tensor, unit: str, fix: str = "") -> None:
    """Raise ``ValueError`` unless ``value`` (a number or 0-d tensor) is finite."""
    number = float(value.detach()) if isinstance(value, torch.Tensor) else float(value)
    if not math.isfinite(number):
        hint = f" Fix: {fix}" if fix else ""
        raise ValueError(f"{name} must be finite; got {number:.6g} {unit}.{hint}")


def require_finite_tensor(name: str, tensor: torch.Tensor) -> None:
    """Raise ``ValueError`` if ``tensor`` holds NaN or Inf, saying how many.

    Fast path: one reduction (a NaN or Inf makes the sum non-finite); the
    element-wise count runs only when that sum is not finite, so huge-but-finite data
    whose sum overflows is still accepted.
    """
    if tensor.numel() == 0:
        return
    total = tensor.sum()
    if bool(torch.isfinite(total)):
        return
    finite = torch.isfinite(tensor)
    if not bool(finite.all()):
        bad = int((~finite).sum())
        raise ValueError(
            f"{name} contains {bad} NaN/Inf value(s) of {tensor.numel()}. "
            "Fix: check the input data or the upstream computation that produced it."
        )


def warn_at_caller(message: str, category: type[Warning]) -> None:
    """Emit ``category`` with ``message``, attributed to the first frame outside ``lfm_studio.engine``
    (the user's call, so the warning shows their line and filters on their module apply)."""
    level = 2  # stacklevel 2: the caller of this function
    frame: FrameType | None = sys._getframe(1)  # f_back is None at the top of the stack
    while frame is not None and frame.f_code.co_filename.startswith(_ENGINE_DIR):
        frame, level = frame.f_back, level + 1
    warnings.warn(message, category, stacklevel=level)


def error_text(error: BaseException) -> str:
    """The message of ``error`` for a user: for a pydantic ``ValidationError`` (a design or spec
    refused), our own text of each problem without pydantic's wrapping (the "1 validation error
    for ...", ``[type=..., input_value=...]`` and the errors.pydantic.dev link); ``str(error)`` else.

    A value error raised by our validators names its parameter, value and fix, so it is shown
    alone; pydantic's own errors (a wrong type, a missing key) keep their location and the value.
    """
    if not isinstance(error, ValidationError):
        return str(error)
    parts = []
    for item in error.errors():
        message = str(item.get("msg", "")).removeprefix("Value error, ")
        loc = ".".join(str(x) for x in item.get("loc", ()))
        if item.get("type") == "value_error" or not loc:
            parts.append(message)
            continue
        value = repr(item.get("input"))
        value = value if len(value) <= 60 else value[:57] + "..."
        parts.append(f"{loc}: {message} (got {value})")
    return "; ".join(parts) or str(error)


def as_real_tensor(name: str, value: object, *, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """``value`` (tensor or array-like: numpy, lists) as a real floating tensor on ``device`` with
    ``dtype``: the one conversion at a public boundary that takes arrays (no copy when ``value``
    already is such a tensor; autograd passes through)."""
    tensor = value if isinstance(value, torch.Tensor) else torch.as_tensor(value)
    if tensor.is_complex():
        raise ValueError(f"{name} must be real (intensities); got a complex {tensor.dtype} tensor.")
    if tensor.dtype == torch.bool:
        raise ValueError(f"{name} must hold numbers; got a boolean tensor.")
    return tensor.to(device=device, dtype=dtype)


def require_non_negative(name: str, tensor: torch.Tensor, fix: str) -> None:
    """Raise ``ValueError`` naming the count and the minimum if ``tensor`` has negative values."""
    require_finite_tensor(name, tensor.detach())
    if tensor.numel() and bool((tensor.detach() < 0).any()):
        bad = int((tensor.detach() < 0).sum())
        low = float(tensor.detach().min())
        raise ValueError(
            f"{name} must be >= 0 (photon counts or intensities); got {bad} negative value(s), "
            f"minimum {low:.6g}. Fix: {fix}"
        )


def require_device(
    device: torch.device | str, *, name: str = "device", fix: str = "pass device='cpu'."
) -> torch.device:
    """``device`` as a ``torch.device`` that this torch build can use, else a ``ValueError`` naming
    ``name``, the device and ``fix`` (CUDA asked for where torch has no CUDA or sees no GPU; an
    unknown device string)."""
    try:
        checked = torch.device(device)
    except (RuntimeError, TypeError) as error:
        raise ValueError(
            f"{name} must be a torch device such as 'cpu' or 'cuda'; got {device!r} ({error}). Fix: {fix}"
        ) from None
    if checked.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(
            f"{name} {str(checked)!r}: no CUDA device is available here (torch.cuda.is_available() is False: "
            f"a CPU-only torch build, or no GPU visible). Fix: {fix}"
        )
    if checked.type == "cuda" and checked.index is not None and checked.index >= torch.cuda.device_count():
        raise ValueError(
            f"{name} {str(checked)!r}: this machine has {torch.cuda.device_count()} CUDA device(s), numbered "
            f"from 0. Fix: {fix}"
        )
    return checked
