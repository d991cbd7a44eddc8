"""Back-focal-plane (pupil) field of a point source seen through the objective.

A source at ``(x0, y0)`` and depth ``z`` (positive away from the objective, see
:mod:`objective`) sends a plane wave at angle ``theta`` that the objective maps to the
pupil height ``rho = n f_obj sin(theta)`` (Abbe sine condition). On the back focal
plane (in air) the field is

    A(rho) = C * P(theta) / cos(theta) * exp(j n k z (cos(theta) - 1))
                * exp(-j k (x x0 + y y0) / f_obj) * [rho <= NA f_obj],

``k = 2 pi / lambda``, ``C = 1 / (sqrt(4 pi) n f_obj)``. The phase constant
``exp(j n k z)`` (depth only) is dropped, and ``n k z (cos(theta) - 1)`` is formed in
float64 in the stable form ``-n k z sin^2(theta) / (1 + cos(theta))``.

``P`` is the Debye apodization (:mod:`objective`); the ``1/cos(theta)`` is the
Jacobian ``rho drho = n^2 f^2 sin(theta) cos(theta) dtheta``, so the tube lens
(a Fourier lens, docs/architecture.md eq. 3.17) turns this field into exactly the image-side
Debye field of :func:`debye_psf` (tested). For the aplanatic ``P = sqrt(cos theta)``
the pupil amplitude is ``1/sqrt(cos theta)`` and the energy per solid angle is uniform:
the normalisation ``C`` makes the pupil power ``integral |A|^2 dA`` equal to the
collected fraction ``(1 - cos(alpha))/2`` of a unit-power isotropic emitter.

``zernike_waves`` (``{noll index: waves}``) adds the phase mask
``2 pi sum_j c_j Z_j(rho_x / (NA f_obj), rho_y / (NA f_obj))`` (:func:`zernike_phase`, unit-RMS
Noll Zernikes over the pupil) to the depth-independent phase: :func:`pupil_terms_at` is the
one place it is formed, so the Fourier LFM's per-lenslet and full-field paths apply it alike.

``model="paraxial"``: ``cos(theta) -> 1`` in the amplitude and the defocus phase
becomes the quadratic ``-k z rho^2 / (2 n f_obj^2)``. It differs from the Debye form by
at most ``(NA/n)^2 / 4`` in amplitude (aplanatic) and ``n k |z| (NA/n)^4 / 8`` rad in phase.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping

import torch

from lfm_studio.engine.dtypes import complex_dtype
from lfm_studio.engine.errors import SamplingWarning, require_positive
from lfm_studio.engine.optics.debye import Device, Scalar, _depths
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.objective import Apodization, ObjectiveLens, _value, resolve_apodization
from lfm_studio.engine.optics.phase_kernels import shift_ramp, wavenumber
from lfm_studio.engine.optics.pupils import disk_coverage, radial_distance
from lfm_studio.engine.optics.zernike import zernike_phase

_MODELS = ("debye", "paraxial")


def _check_sampling(objective: ObjectiveLens, grid: Grid, wavelength: float, z_max: float, r0: float) -> None:
    """Warn when the pupil leaves the window or its phase is undersampled."""
    f = _value(objective.focal_length)
    radius = _value(objective.pupil_radius)
    half_width = min(grid.ny // 2 * grid.dy, grid.nx // 2 * grid.dx)
    if radius > half_width:
        warnings.warn(
            f"pupil radius NA f_obj = {radius * 1e3:.4g} mm exceeds the grid half-width "
            f"{half_width * 1e3:.4g} mm; the pupil is cut by the window. "
            f"Fix: use a grid at least {2 * radius * 1e3:.4g} mm wide (more samples or a larger spacing).",
            SamplingWarning,
            stacklevel=3,
        )
    # Largest phase slope on the pupil: k (|z| tan(alpha) + r0) / f_obj rad per metre.
    alpha = _value(objective.half_angle)
    slope = 2.0 * math.pi / wavelength * (z_max * math.tan(alpha) + r0) / f
    spacing = max(grid.dy, grid.dx)
    if slope * spacing > math.pi:
        warnings.warn(
            f"pupil phase undersampled: the defocus/tilt phase changes by {slope * spacing:.3g} rad per "
            f"sample (limit pi) for |z| = {z_max:.3g} m and lateral offset {r0:.3g} m. "
            f"Fix: grid spacing <= {math.pi / slope:.3g} m, or a smaller depth range.",
            SamplingWarning,
            stacklevel=3,
        )


def pupil_field(
    objective: ObjectiveLens,
    grid: Grid,
    wavelength: float,
    z: Scalar | torch.Tensor,
    *,
    position: tuple[float, float] = (0.0, 0.0),
    center: tuple[float, float] = (0.0, 0.0),
    check_sampling: bool = True,
    model: str = "debye",
    apodization: Apodization = "aplanatic",
    zernike_waves: Mapping[int, Scalar | torch.Tensor] | None = None,
    dtype: torch.dtype = torch.complex64,
    device: Device = None,
) -> Field:
    """Field on the objective's back focal plane for a point source at depth ``z``.

    Parameters
    ----------
    objective : ObjectiveLens
    grid : Grid
        Pupil-plane grid in metres (centred on the optical axis); it should span at
        least the pupil diameter ``2 NA f_obj``.
    wavelength : float
        Vacuum wavelength in metres.
    z : float, 0-d tensor or 1-D tensor ``(Z,)``
        Source depth(s) in metres, positive away from the objective.
    position : (x0, y0)
        Lateral source position in the sample, metres (a linear phase tilt).
    center : (xc, yc)
        Pupil-plane point, metres, at which sample ``N // 2`` of ``grid`` sits (default the
        optical axis); lets a small grid cover one part of the pupil (one lenslet).
    check_sampling : warn when the pupil leaves the window or its phase is undersampled;
        ``False`` for callers that cover part of the pupil on purpose and plan their own grid.
    model : ``"debye"`` (exact ``n k z cos(theta)`` defocus, apodization ``P/cos``) or
        ``"paraxial"`` (quadratic defocus, uniform amplitude).
    apodization : see :mod:`objective` (ignored by the paraxial model).
    zernike_waves : phase mask ``{noll index: waves}`` over the pupil (see the module docstring).
    dtype, device : complex dtype and device of the result.

    Returns
    -------
    Field in air (``refractive_index = 1``) with data ``(Z, ny, nx)`` (``(ny, nx)`` for a
    scalar ``z``), in ``sqrt(W)/m`` for a unit-power emitter; differentiable in ``z``
    and in the objective's focal lengths, magnification and immersion index when they
    are tensors.
    """
    require_positive("wavelength", wavelength, "m", "pass the vacuum wavelength in metres, e.g. 525 * nm.")
    if model not in _MODELS:
        raise ValueError(f"model must be one of {_MODELS}; got {model!r}. Fix: use 'debye' at high NA.")
    zt, scalar_z = _depths(z, device)
    x0, y0 = (float(p) for p in position)
    if check_sampling:
        _check_sampling(objective, grid, wavelength, float(zt.detach().abs().max()), math.hypot(x0, y0))

    amplitude, defocus, tilt = pupil_terms(
        objective,
        grid,
        wavelength,
        position=position,
        center=center,
        model=model,
        apodization=apodization,
        zernike_waves=zernike_waves,
        device=zt.device,
    )
    phase = zt[:, None, None] * defocus + tilt  # (Z, ny, nx), float64
    data = torch.polar(amplitude.expand_as(phase), phase)
    if scalar_z:
        data = data[0]
    return Field(data.to(complex_dtype(dtype)), grid, wavelength, 1.0)


def pupil_terms(
    objective: ObjectiveLens,
    grid: Grid,
    wavelength: float,
    *,
    position: tuple[float, float] = (0.0, 0.0),
    center: tuple[float, float] = (0.0, 0.0),
    model: str = "debye",
    apodization: Apodization = "aplanatic",
    zernike_waves: Mapping[int, Scalar | torch.Tensor] | None = None,
    device: Device = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The depth-independent parts of :func:`pupil_field`, float64 ``(ny, nx)`` each.

    Returns ``(amplitude, defocus, tilt)`` with the pupil field
    ``amplitude * exp(j (z * defocus + tilt))``: ``amplitude`` in ``sqrt(W)/m``,
    ``defocus = n k (cos(theta) - 1)`` in rad per metre of depth, ``tilt`` in rad. A
    caller imaging many depths builds these once and forms only the phase per depth.
    """
    device = torch.device("cpu") if device is None else torch.device(device)
    y, x = grid.axes(device=device)
    return pupil_terms_at(
        objective,
        (x + float(center[0]))[None, :],
        (y + float(center[1]))[:, None],
        wavelength,
        position=position,
        model=model,
        apodization=apodization,
        zernike_waves=zernike_waves,
    )


def pupil_terms_at(
    objective: ObjectiveLens,
    x: torch.Tensor,
    y: torch.Tensor,
    wavelength: Scalar,
    *,
    position: tuple[Scalar, Scalar] = (0.0, 0.0),
    model: str = "debye",
    apodization: Apodization = "aplanatic",
    soft_edge_spacing: Scalar | None = None,
    zernike_waves: Mapping[int, Scalar | torch.Tensor] | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`pupil_terms` at pupil-plane coordinates ``x``, ``y`` (float64, metres, broadcastable).

    Every input may be a tensor (coordinates, wavelength, the objective's fields, the
    source position): the terms keep their graphs. The pupil rim is binary (samples
    inside ``NA f_obj`` count) unless ``soft_edge_spacing`` (the sample spacing of square
    samples, metres, float or 0-d tensor) is given: then the amplitude is weighted by the
    antialiased area coverage of the disk of radius ``NA f_obj`` (:func:`disk_coverage`,
    evaluated in units of samples), which is differentiable in the NA and the spacing.
    ``zernike_waves`` adds its Zernike phase (normalised to the pupil radius ``NA f_obj``)
    to ``tilt``; its coefficients may be tensors.
    """
    if model not in _MODELS:
        raise ValueError(f"model must be one of {_MODELS}; got {model!r}. Fix: use 'debye' at high NA.")
    apod = resolve_apodization(apodization)
    device = x.device

    def as_t(v: Scalar) -> torch.Tensor:
        return (
            v.to(device=device, dtype=torch.float64)
            if isinstance(v, torch.Tensor)
            else torch.tensor(float(v), dtype=torch.float64, device=device)
        )

    x0, y0 = position
    n, f = as_t(objective.immersion_index), as_t(objective.focal_length)
    k = wavenumber(wavelength)
    rho = radial_distance(x, y)
    sin_t = rho / (n * f)
    if soft_edge_spacing is None:
        na_limit = _value(objective.numerical_aperture) / _value(objective.immersion_index)
        # Samples on the rim (to 1e-9 of the radius) count as inside.
        inside = sin_t.detach() <= na_limit * (1.0 + 1e-9)
        sin_t = torch.where(inside, sin_t.clamp(max=na_limit), torch.zeros_like(sin_t))
        weight = None
    else:
        radius = as_t(objective.numerical_aperture) * f
        h = soft_edge_spacing
        weight = disk_coverage(x / h, y / h, radius / h, (1.0, 1.0), antialias=True)
        inside = weight.detach() > 0
        sin_t = torch.where(inside, sin_t.clamp(max=1.0 - 1e-9), torch.zeros_like(sin_t))
    sin2 = sin_t**2
    if model == "debye":
        cos_t = torch.sqrt(1.0 - sin2)
        amplitude = apod(torch.asin(sin_t)) / cos_t
        defocus = -n * k * sin2 / (1.0 + cos_t)  # n k (cos theta - 1), per metre of z
    else:
        amplitude = torch.ones_like(sin2)
        defocus = -n * k * sin2 / 2.0
    amplitude = torch.where(inside, amplitude, torch.zeros_like(amplitude)) / (
        math.sqrt(4.0 * math.pi) * n * f
    )
    if weight is not None:
        amplitude = amplitude * weight
    tilt = shift_ramp(x, y, (x0, y0), k, f)  # -k (x x0 + y y0) / f_obj
    if zernike_waves:
        tilt = tilt + zernike_phase(zernike_waves, x, y, as_t(objective.numerical_aperture) * f)
    amplitude, defocus, tilt = torch.broadcast_tensors(amplitude, defocus, tilt)
    return amplitude, defocus, tilt
