"""Sampled data that knows its physical scale: a ``Volume`` and a ``LightFieldImage``.

Both are frozen dataclasses holding a tensor plus the sampling that gives it a
physical size, so no function needs a loose voxel size passed alongside the data
(docs/architecture.md section 2). Lengths are SI metres.

Position convention (the same as :class:`~lfm_studio.engine.optics.grid.Grid`):
voxel ``i`` of an axis with ``N`` voxels sits at ``(i - N // 2) * d``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import torch

from lfm_studio.engine.errors import require_positive


def _require_real_tensor(name: str, data: Any, ndims: tuple[int, ...], axes: str) -> None:
    if not isinstance(data, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor of shape {axes}; got {type(data).__name__}.")
    if data.is_complex():
        raise TypeError(f"{name} must be real; got {data.dtype}. Fix: store abs(x)**2 or the real part.")
    if data.ndim not in ndims:
        raise ValueError(f"{name} must have shape {axes}; got shape {tuple(data.shape)}.")


def _check_depths(name: str, depths: Any, n: int) -> tuple[float, ...] | None:
    if depths is None:
        return None
    values = tuple(float(z) for z in depths)
    if len(values) != n:
        raise ValueError(
            f"{name} has {n} slices but {len(values)} depths. Fix: give one depth (in metres) per slice."
        )
    if not all(math.isfinite(z) for z in values):
        raise ValueError(f"{name} depths must be finite metres; got {values}.")
    if len(set(values)) != len(values):
        raise ValueError(f"{name} depths must be distinct; got {values}.")
    return values


def voxel_triple(values: Sequence[float]) -> tuple[float, float, float]:
    """``(dz, dy, dx)`` as three floats (metres); ``ValueError`` unless there are exactly three."""
    sizes = tuple(float(v) for v in values)
    if len(sizes) != 3:
        raise ValueError(f"Volume.voxel_size must be (dz, dy, dx) in metres; got {values!r}.")
    return sizes


@dataclass(frozen=True)
class Volume:
    """A sampled 3D volume (or a time series of them) with its voxel size.

    Attributes
    ----------
    data : real tensor, shape ``(Z, Y, X)`` or ``(T, Z, Y, X)``
        Voxel values (e.g. fluorophore density).
    voxel_size : (dz, dy, dx)
        Voxel size in metres.
    depths : tuple of float or None
        Depth of each z slice in metres (may be non-uniform); ``None`` means the
        regular depths ``(i - Z // 2) * dz`` (see :meth:`depth_values`).
    metadata : dict
        Free-form JSON-serialisable provenance.
    """

    data: torch.Tensor
    voxel_size: tuple[float, float, float]
    depths: tuple[float, ...] | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _require_real_tensor("Volume.data", self.data, (3, 4), "(Z, Y, X) or (T, Z, Y, X)")
        sizes = voxel_triple(self.voxel_size)
        for axis, value in zip("zyx", sizes, strict=True):
            require_positive(
                f"Volume.voxel_size d{axis}", value, "m", "give the voxel size in metres, e.g. 2 * um."
            )
        object.__setattr__(self, "voxel_size", sizes)
        object.__setattr__(self, "depths", _check_depths("Volume", self.depths, self.data.shape[-3]))
        object.__setattr__(self, "metadata", dict(self.metadata))

    @property
    def shape(self) -> torch.Size:
        return self.data.shape

    @property
    def extent(self) -> tuple[float, float, float]:
        """Physical size ``(Z dz, Y dy, X dx)`` in metres."""
        (nz, ny, nx), (dz, dy, dx) = self.data.shape[-3:], self.voxel_size
        return (nz * dz, ny * dy, nx * dx)

    def depth_values(self) -> tuple[float, ...]:
        """Depth of each slice in metres: ``depths`` if given, else ``(i - Z // 2) * dz``."""
        if self.depths is not None:
            return self.depths
        nz = self.data.shape[-3]
        return tuple((i - nz // 2) * self.voxel_size[0] for i in range(nz))

    def with_data(self, data: torch.Tensor) -> Volume:
        """Same sampling and metadata, new data of the same number of slices."""
        return replace(self, data=data)

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> Volume:
        """Move to ``device`` and/or cast to a real ``dtype``."""
        return replace(self, data=self.data.to(device=device, dtype=dtype))


@dataclass(frozen=True)
class LightFieldImage:
    """A camera image (e.g. a raw light-field frame) or a time series of them.

    Attributes
    ----------
    data : real tensor, shape ``(Y, X)`` or ``(T, Y, X)``
        Pixel values (counts or intensity).
    pixel_size : float
        Pixel pitch in metres (the sensor pitch for raw camera frames).
    metadata : dict
        Free-form JSON-serialisable provenance (exposure, magnification, ...).
    """

    data: torch.Tensor
    pixel_size: float
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _require_real_tensor("LightFieldImage.data", self.data, (2, 3), "(Y, X) or (T, Y, X)")
        require_positive(
            "LightFieldImage.pixel_size", self.pixel_size, "m", "give the pixel pitch, e.g. 6.5 * um."
        )
        object.__setattr__(self, "pixel_size", float(self.pixel_size))
        object.__setattr__(self, "metadata", dict(self.metadata))

    @property
    def shape(self) -> torch.Size:
        return self.data.shape

    def with_data(self, data: torch.Tensor) -> LightFieldImage:
        """Same pixel size and metadata, new data."""
        return replace(self, data=data)

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> LightFieldImage:
        """Move to ``device`` and/or cast to a real ``dtype``."""
        return replace(self, data=self.data.to(device=device, dtype=dtype))
