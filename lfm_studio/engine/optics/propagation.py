"""Free-space propagation of a :class:`Field` over a distance ``z``: :func:`propagate`.

Methods (``l = lambda / n`` the wavelength in the medium, ``N d`` the window, ``M`` the
padded sample count):

``"asm"``
    Exact angular spectrum, evanescent components dropped (:mod:`asm`). Same grid.
``"bandlimited_asm"``
    ASM with the band limit of Matsushima & Shimobaba (2009) computed from the padded
    window: exact within the limit and never aliased. Same grid.
``"fresnel_tf"``
    Fresnel transfer function ``exp(j k z) exp(-j pi l z f^2)`` (:mod:`fresnel`). Same grid.
``"fresnel_ir"``
    Fresnel impulse response / single FFT (thesis eq. 3.12). Output on a new
    ``M``-sample grid of spacing ``l |z| / (M d)`` (padding refines it; nothing is cropped).
``"auto"``
    See :func:`choose_method`; always returns the input grid.

Padding and cropping happen here only, through :mod:`padding` (centred zeros, default
2x, FFT-friendly sizes). The inverse DFT is done as a forward DFT with its ``1/M`` folded
into the cached kernel and the index reversal undone by the final crop, so a
propagation costs two FFTs, one in-place multiply and the pad/crop copies.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import torch

from lfm_studio.engine.errors import require_finite
from lfm_studio.engine.fft import fft2
from lfm_studio.engine.optics import sampling
from lfm_studio.engine.optics.asm import asm_transfer_function
from lfm_studio.engine.optics.band_loss import check_band_loss
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.fresnel import (
    fresnel_ir_factors,
    fresnel_ir_output_grid,
    fresnel_transfer_factors,
)
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.kernel_cache import KernelCache, KernelKey, default_cache
from lfm_studio.engine.optics.padding import crop_reversed, crop_to, pad_to, padded_shape

METHODS = ("auto", "asm", "bandlimited_asm", "fresnel_tf", "fresnel_ir")
SAME_GRID_METHODS = ("asm", "bandlimited_asm", "fresnel_tf")
# "auto" picks Fresnel only when its phase error at Nyquist is below this (rad): a
# relative field error <= 1e-3 even for content at the band edge.
AUTO_FRESNEL_PHASE_TOLERANCE = 1e-3

Scalar = float | torch.Tensor


def _distance_value(distance: Scalar) -> float:
    if isinstance(distance, torch.Tensor):
        if distance.ndim != 0 or not distance.is_floating_point():
            raise ValueError(
                f"distance must be a float or a 0-d real tensor (metres); got a tensor of shape "
                f"{tuple(distance.shape)} and dtype {distance.dtype}. Fix: propagate depths one at a time, "
                "or stack fields along a batch dimension."
            )
        value = float(distance.detach())
    elif isinstance(distance, (int, float)):
        value = float(distance)
    else:
        raise TypeError(f"distance must be a float or a 0-d tensor in metres; got {type(distance).__name__}.")
    require_finite("distance", value, "m", "give the propagation distance in metres, e.g. 100 * um.")
    return value


def choose_method(field: Field, distance: Scalar, *, padding: float = 2.0) -> str:
    """The method ``method="auto"`` uses for ``field`` over ``distance`` (metres).

    Rule (``l`` wavelength in the medium, ``d`` spacing, ``M`` padded samples):

    1. ``"fresnel_tf"`` when the Fresnel phase error at Nyquist ``1 / (2 d)``,
       ``pi |z| l^3 f^4 / (1 + sqrt(1 - l^2 f^2))^2`` (thesis eq. 3.13), is at most
       ``AUTO_FRESNEL_PHASE_TOLERANCE`` (1e-3 rad) *and* ``|z|`` is within the critical
       distance ``M d^2 / l`` of the padded window (its chirp is sampled). Then Fresnel
       equals the ASM to 1e-3 on every representable frequency, and its separable
       kernel is O(M) to build instead of O(M^2) square roots and exponentials
       (cheaper uncached or with a differentiable distance; the same cost cached).
    2. Otherwise ``"bandlimited_asm"``: exact within the band limit, identical to
       ``"asm"`` up to the critical distance and alias-free beyond it.

    ``"fresnel_ir"`` is never chosen because it changes the grid. In the far field of
    the padded window (Fresnel number ``(M d / 2)^2 / (l |z|) < 1``) :func:`propagate`
    raises :class:`SamplingError` and points to it.
    """
    z = abs(_distance_value(distance))
    wavelength = field.medium_wavelength
    grid = field.grid.with_shape(padded_shape(field.grid.shape, padding))
    nyquist = max(sampling.nyquist_frequency(field.grid))
    fresnel_exact = sampling.fresnel_phase_error(nyquist, wavelength, z) <= AUTO_FRESNEL_PHASE_TOLERANCE
    if fresnel_exact and z <= sampling.critical_distance(grid, wavelength):
        return "fresnel_tf"
    return "bandlimited_asm"


def _build_kernel(
    method: str, grid: Grid, field: Field, distance: Scalar, include_constant_phase: bool, *, combine: bool
) -> tuple[torch.Tensor, ...]:
    """The kernel as a tuple of factors (multiplied in turn; ``fresnel_ir``: first half before the FFT).

    ``combine`` merges separable Fresnel factors into 2D arrays (one multiply pass each, for
    the cache); otherwise they stay 1D (O(M) to build and to store).
    """
    wavelength, dtype, device = field.medium_wavelength, field.dtype, field.device
    constant_phase = include_constant_phase
    scale = 1.0 / (grid.ny * grid.nx)  # the inverse DFT's 1/M, see the module docstring
    if method == "fresnel_ir":
        in_y, in_x, out_y, out_x = fresnel_ir_factors(
            grid, wavelength, distance, include_constant_phase=constant_phase, dtype=dtype, device=device
        )
        # The input chirp only ever multiplies the unpadded field (the padding is zero): crop it.
        in_y, in_x = crop_to(in_y, (field.grid.ny, 1)), crop_to(in_x, (1, field.grid.nx))
        return (in_y * in_x, out_y * out_x) if combine else (in_y, in_x, out_y, out_x)
    if method == "fresnel_tf":
        hy, hx = fresnel_transfer_factors(
            grid,
            wavelength,
            distance,
            scale=scale,
            include_constant_phase=constant_phase,
            dtype=dtype,
            device=device,
        )
        return (hy * hx,) if combine else (hy, hx)
    bandlimit = method == "bandlimited_asm"
    kernel = asm_transfer_function(
        grid, wavelength, distance, bandlimit=bandlimit, scale=scale,
        include_constant_phase=constant_phase, dtype=dtype, device=device,
    )  # fmt: skip
    return (kernel,)


def _kernel(method, grid, field, distance, z, *, cache, include_constant_phase) -> tuple[torch.Tensor, ...]:
    if isinstance(distance, torch.Tensor) and distance.requires_grad:  # uncached, differentiable
        return _build_kernel(method, grid, field, distance, include_constant_phase, combine=False)
    if cache is False:
        return _build_kernel(method, grid, field, z, include_constant_phase, combine=False)
    store = default_cache() if cache is True else cache
    key = KernelKey(
        method=method,
        shape=field.grid.shape,
        padded_shape=grid.shape,
        spacing=grid.spacing,
        wavelength=field.wavelength,
        refractive_index=field.refractive_index,
        distance=z,
        device=str(field.device),
        dtype=field.dtype,
        options=(include_constant_phase,),
    )
    kernel = store.get_or_build(
        key, lambda: _build_kernel(method, grid, field, z, include_constant_phase, combine=True)
    )
    return kernel if isinstance(kernel, tuple) else (kernel,)  # the cache holds what was built: a tuple


def _apply(data: torch.Tensor, factors: tuple[torch.Tensor, ...], in_place: bool) -> torch.Tensor:
    """``data * f1 * f2 ...``, in place when ``data`` is our own temporary and no factor has a graph."""
    for factor in factors:
        data = data.mul_(factor) if in_place and not factor.requires_grad else data * factor
        in_place = True  # from here on ``data`` is ours
    return data


def propagate(
    field: Field,
    distance: Scalar,
    *,
    method: str = "auto",
    padding: float = 2.0,
    cache: bool | KernelCache = True,
    include_constant_phase: bool = True,
    check_sampling: bool = True,
) -> Field:
    """Propagate ``field`` over ``distance`` metres of its medium (``z < 0``: back-propagation).

    Parameters
    ----------
    field : Field
        Data ``(..., ny, nx)``; leading dimensions are propagated together in one call.
    distance : float or 0-d tensor
        ``z`` in metres. With a tensor that requires grad the kernel is built uncached
        and differentiable with respect to it.
    method : {"auto", "asm", "bandlimited_asm", "fresnel_tf", "fresnel_ir"}
        See the module docstring; ``"auto"`` follows :func:`choose_method`.
    padding : float >= 1
        Zero padding factor of the window (next FFT-friendly size). 2 avoids the
        wrap-around of the circular convolution for fields inside the window; 1 is
        exact for periodic fields.
    cache : bool or KernelCache
        Reuse transfer functions (:mod:`kernel_cache`; ``True`` = the shared cache).
    include_constant_phase : bool
        Include ``exp(j k z)`` (``True``: physical, so that fields propagated over
        different distances add coherently with the right relative phase), or drop it
        (the convention of :mod:`sources`, e.g. to compare with ``gaussian_beam``).
    check_sampling : bool
        Run the sampling checks of :mod:`sampling` and :mod:`band_loss` (warnings, and the
        :class:`SamplingError` for far-field and Fresnel-IR windows). ``False`` for
        periodic fields (``padding=1``, where the circular convolution is exact) or
        when the caller has checked.

    Returns
    -------
    Field
        On the input grid, or for ``"fresnel_ir"`` on ``M`` samples of spacing ``l |z| / (M d)``.

    Raises
    ------
    ValueError
        Unknown method, non-finite distance, zero distance with ``"fresnel_ir"``, padding < 1.
    SamplingError
        Padded grid above ``sampling.MAX_GRID_SAMPLES``; far field of the padded window for
        the same-grid methods; Fresnel-IR output window smaller than the field.

    Warns
    -----
    SamplingWarning
        Power at the window edge; Fresnel phase error above pi/2 at Nyquist; band limit
        below Nyquist removing (or an unlimited kernel aliasing) more than 1e-3 of the power.
    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}; got {method!r}.")
    z = _distance_value(distance)
    if method == "fresnel_ir" and z == 0.0:
        raise ValueError(
            "distance must be non-zero for method='fresnel_ir' (its output spacing lambda z / (N dx) "
            "vanishes); got 0.0 m. Fix: use a same-grid method for z = 0."
        )
    shape = padded_shape(field.grid.shape, padding)
    sampling.check_grid_size(shape)
    grid = field.grid.with_shape(shape)
    if method == "auto":
        method = choose_method(field, z, padding=padding)
    wavelength = field.medium_wavelength
    if check_sampling:
        sampling.check_edge_power(field)
        if method in SAME_GRID_METHODS:
            sampling.check_far_field(grid, wavelength, z, method=method)
        if method.startswith("fresnel"):
            sampling.check_fresnel_approximation(field.grid, wavelength, z)
        if method == "fresnel_ir":
            sampling.check_fresnel_ir_support(field, z)

    kernel = _kernel(
        method, grid, field, distance, z, cache=cache, include_constant_phase=include_constant_phase
    )
    if method == "fresnel_ir":
        half = len(kernel) // 2
        out = fft2(pad_to(_apply(field.data, kernel[:half], in_place=False), shape))
        if z < 0:  # exp(+j 2 pi m n / M): the unnormalised inverse DFT, out[(-m) mod M]
            out = crop_reversed(out, shape)
        out = _apply(out, kernel[half:], in_place=True)
        return field.with_data(out, grid=fresnel_ir_output_grid(grid, wavelength, z))

    spectrum = fft2(pad_to(field.data, shape))
    if check_sampling:
        check_band_loss(spectrum, grid, wavelength, z, method=method)
    return field.with_data(crop_reversed(fft2(_apply(spectrum, kernel, in_place=True)), field.grid.shape))
