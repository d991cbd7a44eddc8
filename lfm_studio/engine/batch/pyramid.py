"""The multiscale pyramid of a reconstructed video: 2 x 2 lateral mean downsampling per level.

Level ``k`` has voxels ``2**k`` times wider in y and x (depth and time unchanged); an odd
last row or column is dropped. Each level-``k`` voxel averages the ``2**k x 2**k`` level-0
voxels starting at its index, so its centre lies ``(2**k - 1) / 2`` level-0 voxels further
along y and x: the NGFF translation of that level.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np
import numpy.typing as npt

# The element type a level keeps (a string bound: numpy's scalar types are not subscriptable at run time).
_Item = TypeVar("_Item", bound="np.generic[object]")

MIN_LATERAL = 16  # no level narrower than this (voxels): napari gains nothing from smaller ones
MAX_LEVELS = 4


def level_count(lateral: tuple[int, int], *, max_levels: int = MAX_LEVELS) -> int:
    """Levels for a ``(Y, X)`` volume: halve while both sides stay >= :data:`MIN_LATERAL` (at least 1)."""
    count, (ny, nx) = 1, lateral
    while count < max_levels and min(ny // 2, nx // 2) >= MIN_LATERAL:
        ny, nx, count = ny // 2, nx // 2, count + 1
    return count


def level_shape(shape: tuple[int, ...], level: int) -> tuple[int, ...]:
    """Shape ``(..., Y, X)`` at ``level`` (lateral sides floored by 2 per level)."""
    *lead, ny, nx = shape
    return (*lead, ny >> level, nx >> level)


def downsample(volume: npt.NDArray[_Item]) -> npt.NDArray[_Item]:
    """Mean over 2 x 2 lateral blocks of ``(..., Y, X)`` (odd last row/column dropped), same dtype."""
    ny, nx = (volume.shape[-2] // 2) * 2, (volume.shape[-1] // 2) * 2
    v = volume[..., :ny, :nx]
    blocks = v.reshape(*v.shape[:-2], ny // 2, 2, nx // 2, 2)
    return blocks.mean(axis=(-3, -1), dtype=np.float64).astype(volume.dtype)


def pyramid(volume: npt.NDArray[_Item], levels: int) -> list[npt.NDArray[_Item]]:
    """``[volume, downsample(volume), ...]``, ``levels`` arrays."""
    out = [volume]
    for _ in range(levels - 1):
        out.append(downsample(out[-1]))
    return out


def level_transforms(
    scale: tuple[float, float, float, float], level: int, origin: tuple[float, float, float, float]
) -> list[dict[str, str | list[float]]]:
    """NGFF coordinate transformations of ``level`` for level-0 ``scale`` and ``origin`` (the
    coordinates of level-0 voxel 0), both ``(t, z, y, x)``."""
    factor = float(2**level)
    dt, dz, dy, dx = scale
    t0, z0, y0, x0 = origin
    shift = (factor - 1.0) / 2.0
    return [
        {"type": "scale", "scale": [dt, dz, dy * factor, dx * factor]},
        {"type": "translation", "translation": [t0, z0, y0 + dy * shift, x0 + dx * shift]},
    ]
