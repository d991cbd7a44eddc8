"""The per-frame corrections of a calibration, prepared once and applied to every frame of a series.

A raw frame is corrected by: dark subtraction (the dark frame pixel by pixel, else the dark
level), replacement of the defective pixels by their 3 x 3 median, and division by the
flat field (the frame-wide envelope of a conventional LFM, the per-sub-image gains of a
Fourier LFM). The defect mask, the float64 dark frame and the flat-field map depend only on
the calibration, so :func:`frame_corrections` builds them once; :meth:`FrameCorrections.apply`
then does only the per-frame arithmetic.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lfm_studio.engine.calibration import defects as defect_pixels
from lfm_studio.engine.calibration.checks import as_frame
from lfm_studio.engine.calibration.flat_field import flat_field_map
from lfm_studio.engine.calibration.record import Calibration
from lfm_studio.engine.calibration.sub_image_flat import sub_image_flat_map


@dataclass(frozen=True)
class FrameCorrections:
    """What a calibration does to each raw frame, ready to apply.

    Attributes
    ----------
    frame_shape : (Y, X) px the frames must have.
    defects : (Y, X) bool mask of the pixels replaced by their 3 x 3 median.
    dark : (Y, X) float64 dark frame, or the dark level (float), ADU.
    flat : (Y, X) float64 flat-field map the frame is divided by, or None.
    """

    frame_shape: tuple[int, int]
    defects: torch.Tensor
    dark: torch.Tensor | float
    flat: torch.Tensor | None

    def apply(self, raw: object) -> torch.Tensor:
        """``raw`` (Y, X) corrected, float64; a frame of another shape is refused with the fix."""
        frame = as_frame("raw frame", raw)
        if tuple(frame.shape) != tuple(self.frame_shape):
            raise ValueError(
                f"raw frame shape {tuple(frame.shape)} differs from the calibration's frame shape "
                f"{tuple(self.frame_shape)}. Fix: record the raw frame with the same camera region (ROI) "
                "and binning as the radiometry frame, or calibrate again."
            )
        image = defect_pixels.replace_defects(defect_pixels.subtract_dark(frame, self.dark), self.defects)
        return image if self.flat is None else image / self.flat


def frame_corrections(calibration: Calibration) -> FrameCorrections:
    """The defect mask, dark frame and flat-field map of ``calibration``, computed once."""
    shape = (int(calibration.frame_shape[0]), int(calibration.frame_shape[1]))
    mask = torch.zeros(shape, dtype=torch.bool)
    if calibration.defects.numel():
        mask[calibration.defects[:, 0], calibration.defects[:, 1]] = True
    dark = (
        calibration.dark_frame.to(torch.float64)
        if calibration.dark_frame is not None
        else calibration.dark_level
    )
    flat = None
    if calibration.envelope is not None:
        flat = flat_field_map(calibration.envelope, shape)
    elif calibration.sub_image_flat is not None and calibration.sub_images is not None:
        flat = sub_image_flat_map(calibration.sub_image_flat, calibration.sub_images.measured, shape)
    return FrameCorrections(frame_shape=shape, defects=mask, dark=dark, flat=flat)
