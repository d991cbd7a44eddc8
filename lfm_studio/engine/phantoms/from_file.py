"""A phantom volume loaded from a TIFF (ours or another tool's)."""

from __future__ import annotations

import os
from collections.abc import Sequence

import torch

from lfm_studio.engine.io.containers import Volume
from lfm_studio.engine.io.tiff_io import read_volume


def from_tiff(
    path: str | os.PathLike,
    *,
    voxel_size: Sequence[float | None] | None = None,
    frame: int | None = None,
    normalize: bool = False,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> Volume:
    """Load a ground-truth volume ``(Z, Y, X)`` from a TIFF via :func:`~lfm_studio.engine.io.read_volume`.

    Parameters
    ----------
    path : TIFF file.
    voxel_size : (dz, dy, dx) in metres, overriding the file (entries may be None).
    frame : which time point of a ``(T, Z, Y, X)`` file to take (required for one).
    normalize : scale so the maximum is 1 (an all-zero volume is left as is).
    dtype, device : of the returned data.
    """
    volume = read_volume(path, voxel_size=voxel_size, dtype=dtype, device=device)
    data = volume.data
    if data.ndim == 4:
        if frame is None:
            raise ValueError(
                f"{path} holds {data.shape[0]} time points (T, Z, Y, X). Fix: pass frame=0..{data.shape[0] - 1}."
            )
        if not -data.shape[0] <= frame < data.shape[0]:
            raise ValueError(f"frame {frame} is out of range for {data.shape[0]} time points in {path}.")
        data = data[frame]
    elif frame not in (None, 0):
        raise ValueError(f"{path} holds a single volume; frame must be None or 0, got {frame!r}.")
    if normalize:
        peak = data.max()
        if float(peak) > 0:
            data = data / peak
    return Volume(data, volume.voxel_size, volume.depths, volume.metadata)
