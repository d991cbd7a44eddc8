"""The phase and aperture kernels every element and fast path is built from.

One definition of each piece of thin-element physics (sign convention of docs/architecture.md:
time dependence ``exp(-j w t)``, so a converging lens has a negative quadratic phase):

- :func:`lens_phase` ``-k ((x - cx)^2 + (y - cy)^2) / (2 f)`` (thin lens, thesis eq. 3.15);
- :func:`fresnel_chirp` ``k (x^2 + y^2) / (2 d)`` (input/output chirp of the Fresnel
  integral, thesis eqs. 3.11-3.12);
- :func:`shift_ramp` ``-k (x sx + y sy) / d`` (the cross term of the Fresnel kernel: as an
  input phase it moves a single-FFT Fresnel transform's output by ``(sx, sy)``, an exact
  Fourier-domain sub-pixel shift);
- :func:`aperture_coverage` (disk or square, binary or antialiased area coverage).

Every argument may be a float or a tensor (0-d for the scalars): the result is a
float64 tensor that keeps the autograd graph of every tensor argument. Coordinates,
wavenumbers and distances are in consistent units (metres and rad/m). Callers form
the complex exponential once, from the summed phase.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.optics.pupils import disk_coverage, square_coverage

Scalar = float | torch.Tensor
APERTURE_SHAPES = ("circle", "square")


def wavenumber(wavelength: Scalar) -> Scalar:
    """``k = 2 pi / lambda`` (rad/m) for a wavelength in metres (in the medium)."""
    return 2.0 * math.pi / wavelength


def lens_phase(
    x: torch.Tensor,
    y: torch.Tensor | float,
    focal_length: Scalar,
    k: Scalar,
    center: tuple[Scalar, Scalar] = (0.0, 0.0),
) -> torch.Tensor:
    """Thin-lens phase ``-k ((x - cx)^2 + (y - cy)^2) / (2 f)`` in rad (``f > 0`` converging)."""
    dx, dy = x - center[0], y - center[1]
    return (-0.5 * k) * (dx * dx + dy * dy) / focal_length


def fresnel_chirp(x: torch.Tensor, y: torch.Tensor | float, distance: Scalar, k: Scalar) -> torch.Tensor:
    """Fresnel chirp ``k (x^2 + y^2) / (2 d)`` in rad for a propagation distance ``d``."""
    return (0.5 * k) * (x * x + y * y) / distance


def shift_ramp(
    x: torch.Tensor,
    y: torch.Tensor | float,
    shift: tuple[Scalar, Scalar],
    k: Scalar,
    distance: Scalar,
) -> torch.Tensor:
    """Linear phase ``-k (x sx + y sy) / d`` in rad: the Fresnel kernel's cross term.

    Multiplying the input of a single-FFT Fresnel transform over ``d`` by it moves the
    output samples by ``(sx, sy)`` metres (Fourier shift theorem, any sub-sample amount).
    """
    return (-k / distance) * (x * shift[0] + y * shift[1])


def aperture_coverage(
    shape: str,
    x: torch.Tensor,
    y: torch.Tensor,
    diameter: Scalar,
    spacing: tuple[float, float],
    *,
    antialias: bool,
) -> torch.Tensor:
    """Fraction of each sample's pixel inside a centred aperture (:mod:`pupils`).

    ``shape`` is ``"circle"`` (diameter) or ``"square"`` (side ``diameter``); ``x, y`` are
    coordinates relative to the aperture centre and ``spacing = (dy, dx)`` the pixel size,
    all in the same unit (metres, or samples for a scale-free call).
    """
    if shape == "circle":
        return disk_coverage(x, y, diameter / 2.0, spacing, antialias=antialias)
    if shape == "square":
        return square_coverage(x, y, diameter, spacing, antialias=antialias)
    raise ValueError(f"aperture shape must be one of {APERTURE_SHAPES}; got {shape!r}.")


def unit_phasor(phase: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """``exp(j phase)`` from a float64 phase, cast to the complex ``dtype`` (graph kept)."""
    return torch.complex(torch.cos(phase), torch.sin(phase)).to(dtype)
