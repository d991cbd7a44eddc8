"""Sampling grid of a 2D optical field: shape and pixel spacing in metres.

Convention: sample ``i`` of an axis with ``N`` samples sits at ``(i - N // 2) * d``,
so the optical axis is at index ``N // 2`` (the centre that ``fftshift`` uses).
Frequencies follow the same centred convention: ``(i - N // 2) / (N d)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lfm_studio.engine.errors import require_positive


def _as_pair(value: int | float | tuple, name: str) -> tuple:
    if isinstance(value, (tuple, list)):
        if len(value) != 2:
            raise ValueError(f"{name} must be a number or a (y, x) pair; got {value!r}.")
        return (value[0], value[1])
    return (value, value)


@dataclass(frozen=True)
class Grid:
    """A regular ``(ny, nx)`` grid with spacing ``(dy, dx)`` in metres.

    Parameters
    ----------
    shape : int or (ny, nx)
        Number of samples; a single int means a square grid.
    spacing : float or (dy, dx)
        Sample spacing in metres; a single float means square pixels.
    """

    shape: tuple[int, int]
    spacing: tuple[float, float]

    def __init__(self, shape: int | tuple[int, int], spacing: float | tuple[float, float]):
        ny, nx = _as_pair(shape, "shape")
        dy, dx = _as_pair(spacing, "spacing")
        for axis, n in (("ny", ny), ("nx", nx)):
            if int(n) != n or n < 1:
                raise ValueError(f"Grid shape {axis} must be a positive integer; got {n!r}.")
        require_positive("Grid spacing dy", dy, "m", "give the pixel pitch in metres, e.g. 1 * um.")
        require_positive("Grid spacing dx", dx, "m", "give the pixel pitch in metres, e.g. 1 * um.")
        object.__setattr__(self, "shape", (int(ny), int(nx)))
        object.__setattr__(self, "spacing", (float(dy), float(dx)))

    # -- sizes ---------------------------------------------------------------
    @property
    def ny(self) -> int:
        return self.shape[0]

    @property
    def nx(self) -> int:
        return self.shape[1]

    @property
    def dy(self) -> float:
        """Spacing along y in metres."""
        return self.spacing[0]

    @property
    def dx(self) -> float:
        """Spacing along x in metres."""
        return self.spacing[1]

    @property
    def extent(self) -> tuple[float, float]:
        """Physical size ``(ny * dy, nx * dx)`` in metres."""
        return (self.ny * self.dy, self.nx * self.dx)

    @property
    def pixel_area(self) -> float:
        """Area of one sample in m^2."""
        return self.dy * self.dx

    @property
    def frequency_spacing(self) -> tuple[float, float]:
        """Spatial-frequency spacing ``(1/(ny dy), 1/(nx dx))`` in cycles per metre."""
        return (1.0 / (self.ny * self.dy), 1.0 / (self.nx * self.dx))

    @property
    def max_radius(self) -> float:
        """Distance from the optical axis to the farthest grid corner, in metres."""
        return math.hypot(self.ny // 2 * self.dy, self.nx // 2 * self.dx)

    # -- derived grids -------------------------------------------------------
    def with_shape(self, shape: int | tuple[int, int]) -> Grid:
        """Same spacing, another number of samples (centred on the same axis)."""
        return Grid(shape, self.spacing)

    def with_spacing(self, spacing: float | tuple[float, float]) -> Grid:
        """Same number of samples, another spacing in metres."""
        return Grid(self.shape, spacing)

    def fourier_dual(self, scale: float = 1.0) -> Grid:
        """Grid of the centred DFT of this grid, in cycles/m times ``scale``.

        With ``scale = wavelength * focal_length`` this is the rear-focal-plane
        grid of a Fourier lens: spacing ``lambda f / (N d)`` in metres.
        """
        fy, fx = self.frequency_spacing
        return Grid(self.shape, (fy * scale, fx * scale))

    # -- coordinates ---------------------------------------------------------
    def axes(
        self, *, device: torch.device | str | None = None, dtype: torch.dtype = torch.float64
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """1D coordinates ``(y[ny], x[nx])`` in metres, zero at index ``N // 2``."""
        y = (torch.arange(self.ny, device=device, dtype=dtype) - self.ny // 2) * self.dy
        x = (torch.arange(self.nx, device=device, dtype=dtype) - self.nx // 2) * self.dx
        return y, x

    def frequency_axes(
        self, *, device: torch.device | str | None = None, dtype: torch.dtype = torch.float64
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """1D centred spatial frequencies ``(fy[ny], fx[nx])`` in cycles per metre."""
        dfy, dfx = self.frequency_spacing
        fy = (torch.arange(self.ny, device=device, dtype=dtype) - self.ny // 2) * dfy
        fx = (torch.arange(self.nx, device=device, dtype=dtype) - self.nx // 2) * dfx
        return fy, fx

    def radius_squared(
        self, *, device: torch.device | str | None = None, dtype: torch.dtype = torch.float64
    ) -> torch.Tensor:
        """``x^2 + y^2`` on the grid, shape ``(ny, nx)``, in m^2."""
        y, x = self.axes(device=device, dtype=dtype)
        return y[:, None] ** 2 + x[None, :] ** 2

    def frequency_squared(
        self, *, device: torch.device | str | None = None, dtype: torch.dtype = torch.float64
    ) -> torch.Tensor:
        """``fx^2 + fy^2`` on the centred frequency grid, shape ``(ny, nx)``, in 1/m^2."""
        fy, fx = self.frequency_axes(device=device, dtype=dtype)
        return fy[:, None] ** 2 + fx[None, :] ** 2

    def same_as(self, other: Grid, rtol: float = 1e-9) -> bool:
        """True when shapes match and spacings agree to ``rtol``."""
        return self.shape == other.shape and all(
            math.isclose(a, b, rel_tol=rtol) for a, b in zip(self.spacing, other.spacing, strict=True)
        )
