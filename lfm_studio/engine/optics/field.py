"""The scalar optical ``Field``: complex amplitude, its grid and wavelength.

A ``Field`` carries its own sampling, so no optics function takes a loose ``dx``
or wavelength next to the data. Leading dimensions are batch dimensions
(depth, wavelength, lenslet, ...); the last two are ``(Y, X)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch

from lfm_studio.engine.errors import require_finite_tensor, require_positive
from lfm_studio.engine.optics.grid import Grid


@dataclass(frozen=True)
class Field:
    """Complex scalar field sampled on ``grid``.

    Attributes
    ----------
    data : complex tensor, shape ``(..., ny, nx)``
        Complex amplitude; ``|data|^2`` is irradiance in arbitrary units per m^2.
    grid : Grid
        Sampling of the last two dimensions (spacing in metres).
    wavelength : float
        Vacuum wavelength in metres.
    refractive_index : float
        Index of the medium the field travels in (1.0 for air).
    """

    data: torch.Tensor
    grid: Grid
    wavelength: float
    refractive_index: float = 1.0

    def __post_init__(self) -> None:
        if not isinstance(self.data, torch.Tensor):
            raise TypeError(f"Field.data must be a torch.Tensor; got {type(self.data).__name__}.")
        if not self.data.is_complex():
            raise TypeError(
                f"Field.data must be complex (complex64 or complex128); got {self.data.dtype}. "
                "Fix: build it with torch.complex(real, imag) or multiply by 1+0j."
            )
        if self.data.ndim < 2 or tuple(self.data.shape[-2:]) != self.grid.shape:
            raise ValueError(
                f"Field.data shape {tuple(self.data.shape)} does not end in the grid shape "
                f"{self.grid.shape}. Fix: pass a Grid matching the last two dimensions."
            )
        require_positive(
            "wavelength", self.wavelength, "m", "pass the vacuum wavelength in metres, e.g. 525 * nm."
        )
        require_positive("refractive_index", self.refractive_index, "", "use 1.0 for air, 1.33 for water.")
        require_finite_tensor("Field.data", self.data.detach())

    # -- physical quantities -------------------------------------------------
    @property
    def k(self) -> float:
        """Wavenumber in the medium, ``2 pi n / lambda``, in rad/m."""
        return 2.0 * math.pi * self.refractive_index / self.wavelength

    @property
    def medium_wavelength(self) -> float:
        """Wavelength in the medium, ``lambda / n``, in metres."""
        return self.wavelength / self.refractive_index

    @property
    def shape(self) -> torch.Size:
        return self.data.shape

    @property
    def device(self) -> torch.device:
        return self.data.device

    @property
    def dtype(self) -> torch.dtype:
        return self.data.dtype

    def intensity(self) -> torch.Tensor:
        """``|U|^2`` (irradiance, arbitrary units per m^2), real, same shape as ``data``."""
        return self.data.real**2 + self.data.imag**2

    def power(self) -> torch.Tensor:
        """Total power ``sum |U|^2 dx dy`` over the last two dims, shape ``data.shape[:-2]``."""
        return self.intensity().sum(dim=(-2, -1)) * self.grid.pixel_area

    # -- derived fields ------------------------------------------------------
    def with_data(self, data: torch.Tensor, grid: Grid | None = None) -> Field:
        """Same wavelength and medium, new data (and optionally a new grid)."""
        return replace(self, data=data, grid=self.grid if grid is None else grid)

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> Field:
        """Move to ``device`` and/or cast to a complex ``dtype``."""
        return replace(self, data=self.data.to(device=device, dtype=dtype))

    def require_compatible(self, other: Field, what: str = "fields") -> None:
        """Raise ``ValueError`` unless ``other`` has the same grid and wavelength."""
        if not self.grid.same_as(other.grid):
            raise ValueError(
                f"{what} have mismatched grids: {self.grid} vs {other.grid}. "
                "Fix: resample or pad one field onto the other's grid."
            )
        if not math.isclose(self.wavelength, other.wavelength, rel_tol=1e-12):
            raise ValueError(
                f"{what} have mismatched wavelengths: {self.wavelength} m vs {other.wavelength} m. "
                "Fix: combine only fields of one wavelength (incoherent sums go through intensity)."
            )
