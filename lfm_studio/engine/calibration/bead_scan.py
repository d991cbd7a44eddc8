"""A bead z-scan of a calibrated Fourier LFM, registered to the calibration's optical axis.

A bead-measured PSF (:func:`~lfm_studio.engine.bead_psf.prepare_measured_psf`) is centred on
the bead's centroid, because where the bead sat is unknown. With a calibration it is known
where an on-axis point images: in focus, in each sub-image at the centre of that sub-image
(the image of the field stop, centred on the axis), which is also where the fitted design
(:func:`~lfm_studio.engine.calibration.fitted_design.fitted_design`) puts each lenslet. The
scan is moved so that its in-focus spots land on the measured sub-image centres: a first
shift from the depth-summed centroid (to the mean of the centres, to within a pixel), then the
in-focus spot of each sub-image is measured (iterated centroid within ``SPOT_RADIUS`` px) and
the mean of ``centre - spot`` over the sub-images is the remaining shift (Fourier shift;
ringing below 0 clipped). Sub-pixel registration matters: the in-focus spots are a few pixels
wide, and a PSF off by half a pixel moves every reconstructed bead by half a voxel.
"""

from __future__ import annotations

import dataclasses

import torch

from lfm_studio.engine.bead_psf import fourier_shift
from lfm_studio.engine.calibration.centroids import measure_centroids
from lfm_studio.engine.calibration.record import Calibration
from lfm_studio.engine.psf_stack import PSFStack

SPOT_RADIUS = 6.0  # px


def _plain_centroid(image: torch.Tensor) -> torch.Tensor:
    y = torch.arange(image.shape[0], dtype=torch.float64, device=image.device)
    x = torch.arange(image.shape[1], dtype=torch.float64, device=image.device)
    total = image.sum()
    return torch.stack(((image.sum(dim=1) * y).sum() / total, (image.sum(dim=0) * x).sum() / total)).cpu()


def register_bead_psf(prepared: PSFStack, calibration: Calibration) -> PSFStack:
    """``prepared`` (Z, Y, X) on the calibration's frame moved onto its optical axis (module docstring).

    The total shift (px) is recorded in ``metadata["calibration_shift_px"]``.
    """
    fit = calibration.sub_images
    if fit is None:
        raise ValueError(
            "a bead z-scan is registered to a Fourier-LFM calibration's sub-image centres; this calibration "
            "is of a conventional LFM. Fix: simulate the PSF from the calibration's design instead."
        )
    data = prepared.data.detach().to(torch.float64)
    if tuple(data.shape[-2:]) != tuple(calibration.frame_shape):
        raise ValueError(
            f"the bead PSF images {tuple(data.shape[-2:])} pixels but the calibration's frames have "
            f"{tuple(calibration.frame_shape)}. Fix: record the bead z-scan on the same camera region."
        )
    centres = fit.measured.to(torch.float64)
    coarse = centres.mean(dim=0) - _plain_centroid(data.sum(dim=0))
    focus = min(range(len(prepared.depths)), key=lambda k: abs(prepared.depths[k]))
    in_focus = fourier_shift(data[focus], tuple(coarse.tolist())).clamp_min(0.0).cpu()
    spots = measure_centroids(in_focus, centres, radius=SPOT_RADIUS, iterations=10)
    lit = spots.mass > 0.05 * float(spots.mass.max())
    if not bool(lit.any()):
        raise ValueError(
            "the bead z-scan shows no in-focus spot near the measured sub-image centres. Fix: check that the "
            "scan includes the focal plane and was recorded on the calibrated instrument."
        )
    shift = coarse + (centres[lit] - spots.centres[lit]).mean(dim=0)
    moved = fourier_shift(data, tuple(shift.tolist())).clamp_min(0.0)
    metadata = {**prepared.metadata, "calibration_shift_px": shift.tolist()}
    return dataclasses.replace(prepared, data=moved.to(prepared.data.dtype), metadata=metadata)
