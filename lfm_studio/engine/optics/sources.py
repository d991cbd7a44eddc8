"""Field constructors: plane wave, point source (paraxial and exact spherical), Gaussian beam.

All lengths in metres. ``dtype`` is the complex dtype of the result; phases are
formed in float64 and only the complex exponential is cast (docs/architecture.md section 4).
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.dtypes import complex_dtype
from lfm_studio.engine.errors import require_finite, require_positive
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid

Device = torch.device | str | None


def _check_common(wavelength: float, refractive_index: float) -> None:
    require_positive("wavelength", wavelength, "m", "pass the vacuum wavelength in metres, e.g. 525 * nm.")
    require_positive("refractive_index", refractive_index, "", "use 1.0 for air, 1.33 for water.")


def plane_wave(
    grid: Grid,
    wavelength: float,
    *,
    amplitude: float = 1.0,
    direction_cosines: tuple[float, float] = (0.0, 0.0),
    refractive_index: float = 1.0,
    dtype: torch.dtype = torch.complex64,
    device: Device = None,
) -> Field:
    """Plane wave ``A exp(j k (alpha x + beta y))``.

    ``direction_cosines = (alpha, beta)`` are the direction cosines along x and y
    (``sin`` of the tilt angles); ``(0, 0)`` is a normally incident wave.
    """
    _check_common(wavelength, refractive_index)
    alpha, beta = direction_cosines
    if alpha**2 + beta**2 >= 1.0:
        raise ValueError(
            f"direction_cosines must satisfy alpha^2 + beta^2 < 1; got {direction_cosines!r}. "
            "Fix: use the sines of the tilt angles."
        )
    k = 2.0 * math.pi * refractive_index / wavelength
    y, x = grid.axes(device=device)
    phase = k * (alpha * x[None, :] + beta * y[:, None])
    data = amplitude * torch.polar(torch.ones_like(phase), phase)
    return Field(data.to(complex_dtype(dtype)), grid, wavelength, refractive_index)


def point_source(
    grid: Grid,
    wavelength: float,
    distance: float,
    *,
    position: tuple[float, float] = (0.0, 0.0),
    paraxial: bool = False,
    refractive_index: float = 1.0,
    dtype: torch.dtype = torch.complex64,
    device: Device = None,
) -> Field:
    """Field of a point source seen on a plane ``distance`` metres away.

    Exact spherical wave ``exp(j k r) / r`` with ``r = sqrt(rho^2 + z^2)``; with
    ``paraxial=True`` the Fresnel form ``exp(j k z) exp(j k rho^2 / (2 z)) / z``.
    Negative ``distance`` gives the converging wave (focus ``|z|`` past the plane).
    ``position = (x0, y0)`` is the lateral source position in metres. The constant
    phase ``exp(j k z)`` is dropped in both forms (global phase), so only
    ``k (r - |z|)`` is formed, in the stable form ``k rho^2 / (r + |z|)``.
    """
    _check_common(wavelength, refractive_index)
    require_finite("distance", distance, "m")
    if distance == 0.0:
        raise ValueError("distance must be non-zero for a point source; got 0.0 m. Fix: use e.g. 1 * um.")
    k = 2.0 * math.pi * refractive_index / wavelength
    y, x = grid.axes(device=device)
    x0, y0 = position
    rho2 = (x[None, :] - x0) ** 2 + (y[:, None] - y0) ** 2
    z = abs(distance)
    sign = 1.0 if distance > 0 else -1.0
    if paraxial:
        phase = sign * k * rho2 / (2.0 * z)
        amplitude = torch.full_like(rho2, 1.0 / z)
    else:
        r = torch.sqrt(rho2 + z * z)
        phase = sign * k * rho2 / (r + z)
        amplitude = 1.0 / r
    data = torch.polar(amplitude, phase)
    return Field(data.to(complex_dtype(dtype)), grid, wavelength, refractive_index)


def gaussian_beam(
    grid: Grid,
    wavelength: float,
    waist: float,
    *,
    distance_from_waist: float = 0.0,
    refractive_index: float = 1.0,
    dtype: torch.dtype = torch.complex64,
    device: Device = None,
) -> Field:
    """Paraxial TEM00 Gaussian beam at ``distance_from_waist`` metres past its waist.

    ``U = (w0 / w) exp(-rho^2 / w^2) exp(j k rho^2 / (2 R)) exp(-j psi)`` with
    ``w = w0 sqrt(1 + (z/zR)^2)``, ``R = z (1 + (zR/z)^2)``, Gouy phase
    ``psi = atan(z / zR)`` and ``zR = pi w0^2 n / lambda``; the plane-wave phase
    ``exp(j k z)`` is dropped. Peak amplitude at the waist is 1.
    """
    _check_common(wavelength, refractive_index)
    require_positive("waist", waist, "m", "give the 1/e^2 intensity radius at the waist, e.g. 50 * um.")
    require_finite("distance_from_waist", distance_from_waist, "m")
    z = float(distance_from_waist)
    k = 2.0 * math.pi * refractive_index / wavelength
    z_r = math.pi * waist**2 * refractive_index / wavelength
    w = waist * math.sqrt(1.0 + (z / z_r) ** 2)
    inv_r = z / (z * z + z_r * z_r)  # 1/R, zero at the waist
    gouy = math.atan2(z, z_r)
    rho2 = grid.radius_squared(device=device)
    amplitude = (waist / w) * torch.exp(-rho2 / w**2)
    phase = k * rho2 * inv_r / 2.0 - gouy
    data = torch.polar(amplitude, phase)
    return Field(data.to(complex_dtype(dtype)), grid, wavelength, refractive_index)
