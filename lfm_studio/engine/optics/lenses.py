"""Thin lens (thesis eq. 3.15) and Fourier lens (thesis eq. 3.17) as ``Field -> Field`` functions.

Sign convention (docs/architecture.md): time dependence ``exp(-j w t)``, so a converging lens
(``f > 0``) multiplies by ``exp(-j k (x^2 + y^2) / (2 f))``. ``k`` is the wavenumber
in the field's medium. Phases are formed in float64 and only the complex
exponential is cast to the field's dtype.

``focal_length`` and ``distance`` accept a float or a 0-d tensor; with a tensor,
gradients flow through the lens phase and the Fourier-lens prefactor.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.errors import require_finite, require_positive
from lfm_studio.engine.fft import centered_fft2
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.phase_kernels import lens_phase, unit_phasor
from lfm_studio.engine.optics.pupils import circular_pupil
from lfm_studio.engine.optics.sampling import check_quadratic_phase_sampling

Scalar = float | torch.Tensor


def _value(x: Scalar) -> float:
    return float(x.detach()) if isinstance(x, torch.Tensor) else float(x)


def _float64(x: Scalar, device: torch.device) -> Scalar:
    return x.to(device=device, dtype=torch.float64) if isinstance(x, torch.Tensor) else float(x)


def _farthest_coordinate(grid: Grid, center: tuple[float, float]) -> float:
    """Largest ``|x - cx|`` or ``|y - cy|`` over the samples of ``grid``, in metres.

    The local frequency of a quadratic phase along x is ``(x - cx) / (lambda f)``
    whatever y is, so Nyquist is a per-axis condition on this coordinate (the
    grid corner is not the binding point).
    """
    x_far = max(grid.nx // 2 * grid.dx + center[0], (grid.nx - 1 - grid.nx // 2) * grid.dx - center[0])
    y_far = max(grid.ny // 2 * grid.dy + center[1], (grid.ny - 1 - grid.ny // 2) * grid.dy - center[1])
    return max(x_far, y_far)


def thin_lens(
    field: Field,
    focal_length: Scalar,
    *,
    aperture_diameter: Scalar | None = None,
    center: tuple[float, float] = (0.0, 0.0),
    antialias: bool = False,
) -> Field:
    """Thin lens, thesis eq. 3.15: ``U' = U P(x, y) exp(-j k ((x-cx)^2 + (y-cy)^2) / (2 f))``.

    Parameters
    ----------
    field : Field, data ``(..., ny, nx)``
    focal_length : float or 0-d tensor
        Focal length in metres (> 0, converging).
    aperture_diameter : float or 0-d tensor, optional
        Diameter in metres of the circular pupil ``P``; ``None`` means no pupil
        (the phase covers the whole grid).
    center : (x, y)
        Lens axis in metres relative to the grid's optical axis.
    antialias : bool
        Area-coverage pupil edge (see :mod:`pupils`).

    Returns
    -------
    Field on the same grid.

    Warns
    -----
    SamplingWarning
        When the phase is undersampled at the aperture rim (or the grid edge
        without aperture): ``r_max > lambda f / (2 dx)``.
    """
    require_positive(
        "focal_length", focal_length, "m", "give a converging focal length in metres, e.g. 2 * mm."
    )
    require_finite("center x", center[0], "m")
    require_finite("center y", center[1], "m")
    grid = field.grid
    if aperture_diameter is not None:
        require_positive("aperture_diameter", aperture_diameter, "m", "or pass None for no pupil.")
        r_max = _value(aperture_diameter) / 2.0
    else:
        r_max = _farthest_coordinate(grid, center)
    check_quadratic_phase_sampling(grid, field.medium_wavelength, _value(focal_length), r_max)

    y, x = grid.axes(device=field.device)
    center_xy = (float(center[0]), float(center[1]))
    phase = lens_phase(x[None, :], y[:, None], _float64(focal_length, field.device), field.k, center_xy)
    transmission = unit_phasor(phase, field.dtype)
    out = field.data * transmission
    if aperture_diameter is not None:
        pupil = circular_pupil(
            grid, aperture_diameter, center=center, antialias=antialias, device=field.device
        )
        out = out * pupil.to(field.data.real.dtype)
    return field.with_data(out)


def fourier_lens(field: Field, focal_length: Scalar, *, distance: Scalar) -> Field:
    """Field on the rear focal plane of a lens, object ``distance`` in front (thesis eq. 3.17).

    ``U_f(u, v) = exp[j k/(2f) (1 - d/f) (u^2 + v^2)] / (j lambda f) * FT{U}(u/(lambda f), v/(lambda f))``

    with ``lambda`` and ``k`` in the medium; the constant phase ``exp(j k (d + f))`` is
    dropped. The continuous FT is the centred DFT times ``dx dy``, so the energy
    ``sum |U|^2 dA`` is conserved exactly (Parseval). The lens aperture is taken
    as infinite (apply a pupil first for a finite one). Paraxial.

    Parameters
    ----------
    field : Field, data ``(..., ny, nx)`` on a grid of spacing ``(dy, dx)``
    focal_length : float or 0-d tensor
        Focal length in metres (> 0).
    distance : float or 0-d tensor
        Object-to-lens distance ``d`` in metres; ``d = f`` is the pure optical
        Fourier transform; any finite value is allowed.

    Returns
    -------
    Field on ``field.grid.fourier_dual(lambda f)`` (spacing ``lambda f / (N d)``).
    The output spacing follows the value of ``focal_length``; the gradient with
    respect to ``focal_length`` is that of each output *sample* (whose position
    ``u_i = lambda f fx_i`` moves with ``f``): written per sample, the residual phase
    is ``pi lambda (f - d) (fx^2 + fy^2)``.

    Warns
    -----
    SamplingWarning
        When the residual quadratic phase is undersampled on the output grid,
        i.e. ``|1 - d/f| > N dx^2 / (lambda f)`` (no warning at ``d = f``).
    """
    require_positive(
        "focal_length", focal_length, "m", "give the lens focal length in metres, e.g. 100 * mm."
    )
    require_finite("distance", distance, "m", "give the object-to-lens distance in metres.")
    wavelength = field.medium_wavelength
    f, d = _value(focal_length), _value(distance)
    out_grid = field.grid.fourier_dual(wavelength * f)
    defocus = abs(1.0 - d / f)
    if defocus > 0.0:
        check_quadratic_phase_sampling(
            out_grid, wavelength, f / defocus, _farthest_coordinate(out_grid, (0.0, 0.0))
        )

    fy, fx = field.grid.frequency_axes(device=field.device)
    rho2 = fy[:, None] ** 2 + fx[None, :] ** 2
    f64, d64 = _float64(focal_length, field.device), _float64(distance, field.device)
    phase = (math.pi * wavelength) * (f64 - d64) * rho2
    # 1 / (j lambda f) = -j / (lambda f); the DFT times dx dy approximates the continuous FT.
    scale = field.grid.pixel_area / (wavelength * f64)
    kernel = torch.complex(torch.sin(phase), -torch.cos(phase)) * scale
    spectrum = centered_fft2(field.data)
    return Field(spectrum * kernel.to(field.dtype), out_grid, field.wavelength, field.refractive_index)
