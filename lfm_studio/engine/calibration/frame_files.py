"""Radiometry, dark and raw frames from TIFF files, with errors that name the option or field."""

from __future__ import annotations

from pathlib import Path

import torch


def read_frame(option: str, path: str | Path, pixel_size: float) -> torch.Tensor:
    """One (Y, X) frame from a TIFF, float64 ADU; a (T, Y, X) stack of exposures is averaged.

    ``option`` names the input in errors (``--radiometry``, "radiometry frame"); ``pixel_size``
    (metres) is used when the file does not record one.
    """
    from lfm_studio.engine.io import read_image

    if not Path(path).is_file():
        raise FileNotFoundError(f"{option} {path}: no such file. Fix: give the path to a TIFF frame.")
    data = read_image(path, pixel_size=pixel_size, dtype=torch.float64).data
    return data.mean(dim=0) if data.ndim == 3 else data
