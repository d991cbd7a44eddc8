"""``Phantom``: a synthetic volume with the ground truth of what was put in it.

Positions use the engine's centred convention (as :class:`~lfm_studio.engine.optics.grid.Grid`):
voxel ``i`` of an axis with ``N`` voxels sits at ``(i - N // 2) * d`` metres, so the
volume centre (index ``N // 2``) is at 0 and the depth of slice ``k`` is ``(k - Z // 2) * dz``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from lfm_studio.engine.io.containers import Volume


@dataclass(frozen=True)
class Phantom:
    """A synthetic volume and the objects (beads or cells) it contains.

    Attributes
    ----------
    data : real tensor, shape ``(Z, Y, X)``
        The volume.
    voxel_size : (dz, dy, dx)
        Voxel size in metres.
    positions : float64 tensor, shape ``(N, 3)``, CPU
        Object centres ``(z, y, x)`` in metres (centred convention above).
    indices : int64 tensor, shape ``(N, 3)``, CPU
        Nearest voxel ``(iz, iy, ix)`` of each centre.
    semi_axes : float64 tensor, shape ``(N, 3)``, CPU
        Object semi-axes ``(z, y, x)`` in metres (zeros for point beads).
    intensities : float64 tensor, shape ``(N,)``, CPU
        Peak value of each object.
    """

    data: torch.Tensor
    voxel_size: tuple[float, float, float]
    positions: torch.Tensor
    indices: torch.Tensor
    semi_axes: torch.Tensor
    intensities: torch.Tensor

    @property
    def count(self) -> int:
        """Number of objects."""
        return int(self.positions.shape[0])

    def depths(self) -> tuple[float, ...]:
        """Depth of each z slice in metres, ``(k - Z // 2) * dz``."""
        nz = self.data.shape[-3]
        return tuple((k - nz // 2) * self.voxel_size[0] for k in range(nz))

    def to_volume(self, metadata: dict[str, Any] | None = None) -> Volume:
        """The volume with its voxel size (for :func:`~lfm_studio.engine.io.write_volume`)."""
        return Volume(self.data, self.voxel_size, None, metadata or {})


def make_generator(seed: int | torch.Generator) -> torch.Generator:
    """A CPU generator from an int seed, or the caller's CPU generator.

    Phantoms are drawn on the CPU so the same seed gives the same phantom on every device.
    """
    if isinstance(seed, torch.Generator):
        if seed.device.type != "cpu":
            raise ValueError(
                f"seed must be an int or a CPU torch.Generator; got a generator on {seed.device}. "
                "Fix: pass torch.Generator().manual_seed(n) (phantoms are drawn on the CPU so a seed "
                "gives the same volume on every device)."
            )
        return seed
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise TypeError(f"seed must be an int or a torch.Generator; got {seed!r}.")
    return torch.Generator().manual_seed(seed)


def check_shape(shape: Any) -> tuple[int, int, int]:
    """``(Z, Y, X)`` as three positive ints."""
    values = tuple(shape) if isinstance(shape, (tuple, list, torch.Size)) else (shape,)
    if len(values) != 3 or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 1 for n in values):
        raise ValueError(f"shape must be three positive ints (Z, Y, X); got {shape!r}.")
    return values


def check_triple(
    name: str, values: Any, *, allow_zero: bool = False, hint: str
) -> tuple[float, float, float]:
    """Three finite lengths in metres, each > 0 (or >= 0 with ``allow_zero``), as floats."""
    try:
        triple = tuple(float(v) for v in values)
    except TypeError:
        triple = ()
    if len(triple) != 3:
        raise ValueError(f"{name} must be three lengths (z, y, x) in metres; got {values!r}. Fix: {hint}")
    for axis, value in zip("zyx", triple, strict=True):
        ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
        if not ok:
            limit = ">= 0" if allow_zero else "> 0"
            raise ValueError(f"{name} {axis} must be finite and {limit} m; got {value:.6g} m. Fix: {hint}")
    return triple


def check_count(count: Any) -> int:
    """A non-negative int count."""
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise ValueError(f"count must be an int >= 0; got {count!r}.")
    return count


def centre_index(shape: tuple[int, int, int]) -> torch.Tensor:
    """Index of the origin along each axis, ``N // 2``, as float64 ``(3,)``."""
    return torch.tensor([n // 2 for n in shape], dtype=torch.float64)


def check_dtype(dtype: torch.dtype) -> torch.dtype:
    """A real floating dtype for a phantom volume."""
    if not isinstance(dtype, torch.dtype) or not dtype.is_floating_point:
        raise TypeError(f"dtype must be a real floating torch dtype (float32, float64); got {dtype!r}.")
    return dtype
