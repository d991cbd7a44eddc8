"""Input checks and guarded divisions shared by every reconstruction method.

Unit: the camera image is in photons with the camera's baseline removed (what
:func:`lfm_studio.engine.io.counts_to_photons` returns), and the volume comes out in photons
per voxel. An integer image (raw camera counts, e.g. uint16 ADU) is reconstructed but warned
about (:class:`RawCountsWarning`).

Numerics rules (docs/architecture.md section 4): divisions are guarded by a floor *relative to
the data scale* (an absolute ``1e-12`` vanishes next to float32 values of 1e4, and is
below float32's smallest normal number times a typical PSF value), estimates stay
non-negative, and NaN/Inf, negative or empty inputs are rejected with a ``ValueError``
that names the parameter, the value, the limit and a fix.

The relative floor is ``RELATIVE_FLOOR_ULPS * eps(dtype)``: an FFT convolution of a
non-negative signal is exact to about ``eps * log2(N)`` of its largest value, so
anything below that floor is rounding noise, not signal.
"""

from __future__ import annotations

import numpy as np
import torch

from lfm_studio.engine.errors import (
    as_real_tensor,
    require_finite_tensor,
    require_non_negative,
    warn_at_caller,
)
from lfm_studio.engine.operators.protocol import Projector
from lfm_studio.engine.types import Scalar, Shape2, Shape3, TensorLike

RELATIVE_FLOOR_ULPS = 16.0  # FFT rounding of a 2400^2 transform: log2(N) ~ 22 ulps at most, ~4 typical


class RawCountsWarning(UserWarning):
    """A reconstruction was given an integer image: raw camera counts (ADU), not photons."""


def relative_floor(dtype: torch.dtype) -> float:
    """Floor relative to the data scale for ``dtype``: ``16 eps`` (1.9e-6 in float32, 3.6e-15 in float64)."""
    return RELATIVE_FLOOR_ULPS * torch.finfo(dtype).eps


def require_shape(name: str, tensor: torch.Tensor, shape: tuple[int, ...], meaning: str) -> None:
    """Raise ``ValueError`` unless ``tensor.shape == shape``."""
    if tuple(tensor.shape) != tuple(shape):
        raise ValueError(
            f"{name} must have shape {tuple(shape)} {meaning}; got {tuple(tensor.shape)}. "
            "Fix: use the projector built for this image and volume grid."
        )


def is_integer_data(value: object) -> bool:
    """Whether ``value`` is a tensor or array of an integer dtype (not bool, float or complex)."""
    dtype = getattr(value, "dtype", None)
    if isinstance(dtype, torch.dtype):
        return not (dtype.is_floating_point or dtype.is_complex or dtype == torch.bool)
    return isinstance(dtype, np.dtype) and dtype.kind in "iu"


def warn_if_raw_counts(name: str, image: object) -> None:
    """Warn (:class:`RawCountsWarning`, at the user's call) when ``image`` has an integer dtype: most
    likely raw camera counts (ADU, baseline included), where the methods take photons."""
    if not is_integer_data(image):
        return
    dtype = str(getattr(image, "dtype", "")).removeprefix("torch.")
    warn_at_caller(
        f"{name} has the integer dtype {dtype}: raw camera counts (ADU, with the camera's baseline)? The "
        "reconstruction takes photons with the baseline removed and returns photons per voxel; from counts "
        "the volume is in the wrong unit and the baseline is reconstructed as light. Fix: convert first, "
        "photons, background = lfm_studio.engine.io.counts_to_photons(counts, calibration, name=...) with "
        "calibration = CameraCalibration(baseline_adu, gain_adu_per_e, quantum_efficiency) or from "
        "resolve_calibration(...), and pass background=background; if the values are photons already, pass "
        "them as floats (.float() on a tensor, .astype(numpy.float32) on an array).",
        RawCountsWarning,
    )


def check_image(
    image: TensorLike, shape: Shape2, *, dtype: torch.dtype, device: torch.device, non_negative: bool = True
) -> torch.Tensor:
    """The camera image as a checked ``(Py, Px)`` tensor: finite, right shape and (for RL) non-negative.

    The image is in photons, baseline removed (:func:`lfm_studio.engine.io.counts_to_photons`); an
    integer dtype (raw counts) is warned about (:func:`warn_if_raw_counts`). Values that are negative
    only by rounding (``>= -16 eps max|image|``, e.g. a projector's FFT output) are set to 0; anything
    more negative is rejected when ``non_negative``.
    """
    warn_if_raw_counts("image", image)
    tensor = as_real_tensor("image", image, dtype=dtype, device=device)
    require_shape("image", tensor, shape, "(Py, Px) camera pixels")
    require_finite_tensor("image", tensor.detach())
    if not non_negative or tensor.numel() == 0:
        return tensor
    rounding = relative_floor(dtype) * float(tensor.detach().abs().max())
    if bool((tensor.detach() < 0).any()) and float(tensor.detach().min()) >= -rounding:
        tensor = tensor.clamp_min(0.0)
    require_non_negative(
        "image",
        tensor,
        "subtract the camera baseline (offset) and clip at 0 with image.clamp(min=0), or pass the "
        "offset as `background` instead of subtracting it.",
    )
    return tensor


def check_background(
    background: Scalar, shape: Shape2, *, dtype: torch.dtype, device: torch.device
) -> torch.Tensor:
    """Background ``b`` (photons per pixel, the image's unit; a number or a tensor broadcastable to
    ``shape``), >= 0."""
    tensor = as_real_tensor("background", background, dtype=dtype, device=device)
    try:
        torch.broadcast_shapes(tuple(tensor.shape), tuple(shape))
    except RuntimeError:
        raise ValueError(
            f"background must be a number or broadcast to the image shape {tuple(shape)}; "
            f"got shape {tuple(tensor.shape)}."
        ) from None
    require_non_negative(
        "background", tensor, "give the mean background per pixel (photons, the image's unit), e.g. 0."
    )
    return tensor


def check_signal(image: torch.Tensor, background: torch.Tensor) -> float:
    """Total signal above the background, in the image's unit (photons or counts); raise if there is
    none (a zero-photon image)."""
    total = float((image.double() - background.double()).sum())
    if not total > 0:
        raise ValueError(
            f"image has no signal above the background: sum(image - background) = {total:.6g} in the "
            "image's unit (must be > 0). Fix: check that the image is not all zero (no photons reached the camera), "
            "that it is the right frame, and that `background` is not larger than the image."
        )
    return total


def check_sensitivity(sensitivity: torch.Tensor, what: str = "A^T 1") -> None:
    """Raise if the back-projected ones (voxel sensitivity) are not finite or all zero (an all-zero PSF)."""
    require_finite_tensor(f"sensitivity {what}", sensitivity.detach())
    if not float(sensitivity.detach().double().sum()) > 0:
        raise ValueError(
            f"the projector's sensitivity {what} is zero everywhere: its PSF is all zero, so no voxel "
            "reaches the camera. Fix: check the PSF stack (simulation output, or the measured TIFF "
            "after background subtraction)."
        )


def check_estimate(
    name: str, value: TensorLike, shape: Shape3, *, dtype: torch.dtype, device: torch.device
) -> torch.Tensor:
    """A starting volume ``(Z, Y, X)``: finite, non-negative and not all zero (a fixed point of RL)."""
    tensor = as_real_tensor(name, value, dtype=dtype, device=device)
    require_shape(name, tensor, shape, "(Z, Y, X) voxels")
    require_non_negative(name, tensor, "start from a non-negative volume (default: uniform).")
    if not float(tensor.detach().double().sum()) > 0:
        raise ValueError(
            f"{name} is all zero: multiplicative updates can never leave zero. Fix: pass None for the "
            "flux-matched uniform start, or a positive volume."
        )
    return tensor.clone()


def floored(denominator: torch.Tensor, scale: float, dtype: torch.dtype) -> torch.Tensor:
    """``denominator`` clamped below at ``relative_floor(dtype) * scale`` (``scale`` > 0: the data scale)."""
    return denominator.clamp_min(relative_floor(dtype) * scale)


def check_iterations(iterations: object) -> int:
    """A positive int iteration count."""
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
        raise ValueError(f"iterations must be an int >= 1; got {iterations!r}. Fix: e.g. iterations=30.")
    return iterations


def check_rtol(rtol: float | None) -> float | None:
    """``None`` (run all iterations) or a finite relative-change threshold > 0."""
    if rtol is None:
        return None
    value = float(rtol)
    if not (value > 0 and value < float("inf")):
        raise ValueError(
            f"rtol must be a finite number > 0 (relative change ||x_k+1 - x_k|| / ||x_k||); got {rtol!r}. "
            "Fix: e.g. rtol=1e-3, or None to run every iteration."
        )
    return value


def working_dtype_device(projector: Projector) -> tuple[torch.dtype, torch.device]:
    """dtype and device of the projector, where every reconstruction runs (float32 or float64)."""
    dtype = projector.dtype
    if dtype not in (torch.float32, torch.float64):
        raise ValueError(f"reconstruction runs in float32 or float64; the projector has {dtype}.")
    return dtype, torch.device(projector.device)
