"""A calibration: everything measured on a radiometry (and dark) frame, as one immutable record."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from lfm_studio.engine.calibration.grid_fit import LatticeFit
from lfm_studio.engine.calibration.sub_image_flat import SubImageFlat
from lfm_studio.engine.calibration.sub_images import SubImageFit

CALIBRATION_VERSION = 2  # 2: the Fourier LFM per-sub-image flat field


@dataclass(frozen=True)
class Calibration:
    """A measured instrument geometry and the corrections for its raw frames.

    Attributes
    ----------
    kind : "conventional" or "fourier" (the design's kind).
    frame_shape : (Y, X) of the frames it was measured on, px.
    design : the nominal design, as its JSON dict.
    dark_level : dark offset, ADU: the dark frame's median, or the design camera's baseline
        (then subtracted from raw frames) when no dark frame was given.
    defects : (K, 2) int64 (y, x) of hot and dead pixels (replaced by their 3 x 3 median).
    envelope : flat-field polynomial coefficients (see :mod:`.flat_field`), or None.
    pixels_per_lenslet : rectified pixels per lenslet (conventional; None for Fourier).
    block : (i0, ni, j0, nj) lenslet rows and columns rectified by default (conventional).
    grid : the lattice fit (conventional) or None.
    sub_images : the sub-image fit (Fourier) or None.
    dark_frame : (Y, X) float32 dark frame subtracted pixel by pixel from raw frames, ADU, or None.
    sub_image_flat : the per-sub-image gains of a Fourier LFM (:mod:`.sub_image_flat`), or None
        (conventional LFM, or a version-1 Fourier calibration: no flat field).
    version : :data:`CALIBRATION_VERSION`.
    """

    kind: str
    frame_shape: tuple[int, int]
    design: dict[str, Any]
    dark_level: float
    defects: torch.Tensor
    envelope: torch.Tensor | None
    pixels_per_lenslet: int | None
    block: tuple[int, int, int, int] | None
    grid: LatticeFit | None
    sub_images: SubImageFit | None
    dark_frame: torch.Tensor | None = None
    sub_image_flat: SubImageFlat | None = None
    version: int = CALIBRATION_VERSION

    def __post_init__(self) -> None:
        if self.kind not in ("conventional", "fourier"):
            raise ValueError(f"Calibration.kind must be 'conventional' or 'fourier'; got {self.kind!r}.")
        if (self.kind == "conventional") != (self.grid is not None):
            raise ValueError(
                "a conventional calibration has a lattice fit (grid) and a Fourier one has none."
            )
        if self.dark_frame is not None and tuple(self.dark_frame.shape) != tuple(self.frame_shape):
            raise ValueError(
                f"Calibration.dark_frame shape {tuple(self.dark_frame.shape)} differs from frame_shape "
                f"{tuple(self.frame_shape)}."
            )
        if (self.kind == "fourier") != (self.sub_images is not None):
            raise ValueError("a Fourier calibration has a sub-image fit and a conventional one has none.")
        if self.sub_image_flat is not None and (
            self.sub_images is None
            or self.sub_image_flat.coefficients.shape[0] != self.sub_images.measured.shape[0]
        ):
            raise ValueError("a per-sub-image flat field needs one gain polynomial per measured sub-image.")

    def summary(self) -> dict[str, Any]:
        """Numbers a person checks first (pitch, rotation, residuals, flagged counts)."""
        if self.grid is not None:
            lattice = self.grid.lattice
            return {
                "kind": self.kind,
                "pitch_yx_px": list(lattice.pitch),
                "rotation_deg": math.degrees(lattice.rotation),
                "origin_yx_px": list(lattice.origin),
                "lenslets": int(self.grid.indices.shape[0]),
                "flagged": int((self.grid.flags != 0).sum()),
                "rms_residual_px": self.grid.rms_residual,
                "defect_pixels": int(self.defects.shape[0]),
            }
        fit = self.sub_images
        if fit is None:  # excluded by __post_init__
            raise ValueError("a Fourier calibration needs its sub-image fit.")
        used = fit.flags == 0
        return {
            "kind": self.kind,
            "sub_images": int(fit.measured.shape[0]),
            "flagged": int((~used).sum()),
            "scale": fit.scale,
            "rotation_deg": math.degrees(fit.rotation),
            "shift_yx_px": list(fit.shift),
            "rms_residual_px": float(fit.residual[used].pow(2).mean().sqrt()),
            "defect_pixels": int(self.defects.shape[0]),
        }
