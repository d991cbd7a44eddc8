"""Fourier LFM / XLFM: the centre of each lenslet's sub-image on a radiometry frame.

A uniform slide fills each sub-image with a disk (the field stop's image). Around each
nominal centre the disk is thresholded at half its brightness (a soft ramp from 3/8 to 5/8
of the 95th percentile of the disk's core, within ``CORE`` of the nominal radius, so
vignetting across the disk and a brighter neighbour do not pull the centre) and its
centroid is iterated inside a window of radius ``min(D/2 + 2 px, s/2)`` (a sub-image whose
disk, plus 1 px, leaves the frame is flagged ``EDGE``) (``D`` the nominal diameter, ``s``
the closest nominal spacing). The measured centres are then registered to the nominal ones
by a least-squares similarity transform (scale, rotation, shift); the distance of each
measured centre from the registered nominal one is its residual. Outliers are flagged: a
sub-image with under half the median light, and, one at a time, the sub-image whose
leave-one-out residual (from the transform fitted to the others) exceeds ``max(6 robust
sigmas of the others, 1 px)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lfm_studio.engine.calibration.centroids import measure_centroids
from lfm_studio.engine.calibration.grid_fit import DIM, EDGE, RESIDUAL, disk_leaves_frame
from lfm_studio.engine.calibration.nominal import NominalSubImages, min_spacing

ITERATIONS = 12
RESIDUAL_SIGMAS = 6.0
RESIDUAL_FLOOR = 1.0  # px
CORE = 0.7  # the threshold's brightness is taken within this fraction of the nominal radius


@dataclass(frozen=True)
class SubImageFit:
    """Measured sub-image centres and their registration to the design.

    Attributes
    ----------
    nominal, measured : (L, 2) float64 (y, x) px, in design lenslet order.
    residual : (L,) px, measured minus registered nominal.
    light : (L,) background-subtracted light per sub-image.
    flags : (L,) int64 bit set of ``EDGE | DIM | RESIDUAL`` (as for the lattice fit).
    scale, rotation : similarity transform nominal -> measured (rotation in radians).
    shift : (dy, dx) px of the transform.
    """

    nominal: torch.Tensor
    measured: torch.Tensor
    residual: torch.Tensor
    light: torch.Tensor
    flags: torch.Tensor
    scale: float
    rotation: float
    shift: tuple[float, float]

    def registered(self) -> torch.Tensor:
        """(L, 2) the nominal centres moved by the fitted similarity transform, px."""
        a, b = self.scale * math.cos(self.rotation), self.scale * math.sin(self.rotation)
        return _apply(torch.tensor([a, b, *self.shift], dtype=torch.float64), self.nominal)


def _similarity(nominal: torch.Tensor, measured: torch.Tensor) -> torch.Tensor:
    """Least-squares ``(a, b, ty, tx)`` with ``y' = a y + b x + ty``, ``x' = -b y + a x + tx``."""
    y, x = nominal[:, 0], nominal[:, 1]
    one, zero = torch.ones_like(y), torch.zeros_like(y)
    rows = torch.cat((torch.stack((y, x, one, zero), 1), torch.stack((x, -y, zero, one), 1)))
    target = torch.cat((measured[:, 0], measured[:, 1]))
    return torch.linalg.lstsq(rows, target[:, None]).solution[:, 0]


def _apply(params: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    a, b, ty, tx = params.tolist()
    y, x = points[:, 0], points[:, 1]
    return torch.stack((a * y + b * x + ty, -b * y + a * x + tx), 1)


def check_frame_holds_sub_images(shape: tuple[int, int], nominal: NominalSubImages) -> None:
    """Raise ``ValueError`` when fewer than 2 of the design's sub-images lie whole on a frame of ``shape``
    (a frame from another instrument, or a crop): the error names the frame's shape and the span the
    design's sub-images need."""
    whole = ~disk_leaves_frame(nominal.centres, torch.Size(shape), 0.5 * nominal.diameter)
    if int(whole.sum()) >= 2:
        return
    centres = nominal.centres
    span_y, span_x = (float(centres[:, i].max() - centres[:, i].min()) + nominal.diameter for i in (0, 1))
    raise ValueError(
        f"the radiometry frame is {shape[0]} x {shape[1]} px, but the design's {len(centres)} sub-images "
        f"(each {nominal.diameter:.4g} px across) span about {math.ceil(span_y)} x {math.ceil(span_x)} px "
        f"around the frame centre: only {int(whole.sum())} of them would lie whole on it (at least 2 are "
        "needed to register them). Fix: give the whole camera frame the design describes, or the design "
        "of the instrument that recorded this frame (its camera pixel size and lenslet centres)."
    )


def fit_sub_images(image: torch.Tensor, nominal: NominalSubImages, *, background: float = 0.0) -> SubImageFit:
    """Measure and register the sub-image centres of a dark-subtracted radiometry ``image`` (Y, X).

    A frame on which fewer than 2 nominal sub-images lie whole is refused first
    (:func:`check_frame_holds_sub_images`); a sub-image whose window misses the frame entirely
    keeps its nominal centre and no light, and is flagged ``EDGE``.
    """
    check_frame_holds_sub_images((int(image.shape[0]), int(image.shape[1])), nominal)
    radius = min(0.5 * nominal.diameter + 2.0, 0.5 * min_spacing(nominal.centres))
    measured, light = [], []
    lit = (image.to(torch.float64) - background).clamp_min(0.0)
    reach = math.ceil(radius) + 8  # the window may wander a few pixels while it converges
    for centre in nominal.centres:
        cy, cx = (round(float(v)) for v in centre)
        y0, x0 = max(cy - reach, 0), max(cx - reach, 0)
        crop = lit[y0 : cy + reach + 1, x0 : cx + reach + 1]
        if crop.numel() == 0:  # off the frame: flagged EDGE below (its disk leaves the frame)
            measured.append(centre.clone())
            light.append(0.0)
            continue
        # The brightness of this sub-image: its core only, so a brighter neighbour (another
        # vignetting) reaching into the window does not raise the threshold.
        yy = torch.arange(y0, y0 + crop.shape[0], dtype=torch.float64)[:, None] - float(centre[0])
        xx = torch.arange(x0, x0 + crop.shape[1], dtype=torch.float64)[None, :] - float(centre[1])
        core = crop[yy**2 + xx**2 <= (CORE * 0.5 * nominal.diameter) ** 2]
        core = core if core.numel() else crop.reshape(-1)
        peak = float(torch.quantile(core[:: max(1, core.numel() // 200_000)], 0.95))
        ramp = ((crop - 0.5 * peak) / (0.25 * peak) + 0.5).clamp(0.0, 1.0) if peak > 0 else crop * 0
        corner = torch.tensor([y0, x0], dtype=torch.float64)
        spot = measure_centroids(ramp, centre[None] - corner, radius=radius, iterations=ITERATIONS)
        measured.append(spot.centres[0] + corner)
        light.append(float(spot.mass[0]) * peak)
    measured_t = torch.stack(measured)
    light_t = torch.tensor(light, dtype=torch.float64)
    edge = disk_leaves_frame(measured_t, image.shape, 0.5 * nominal.diameter + 1.0)
    flags = torch.where(edge, EDGE, 0) | torch.where(light_t < 0.5 * light_t.median(), DIM, 0)
    keep = flags == 0
    if int(keep.sum()) < 2:
        raise ValueError(
            f"only {int(keep.sum())} of {len(keep)} sub-images were found whole on the radiometry frame; "
            "at least 2 are needed to register them. Fix: check that the frame shows the sub-images "
            "and that the design's lenslet centres and pixel size match the instrument."
        )
    while int(keep.sum()) > 3:  # leave-one-out: drop the worst sub-image while it is an outlier
        worst, worst_residual, sigma = -1, 0.0, 0.0
        for i in torch.nonzero(keep)[:, 0].tolist():
            others = keep.clone()
            others[i] = False
            params = _similarity(nominal.centres[others], measured_t[others])
            residual = torch.linalg.vector_norm(measured_t - _apply(params, nominal.centres), dim=1)
            if float(residual[i]) > worst_residual:
                worst, worst_residual = i, float(residual[i])
                sigma = 1.4826 * float(residual[others].median())
        if worst_residual <= max(RESIDUAL_SIGMAS * sigma, RESIDUAL_FLOOR):
            break
        keep[worst] = False
    params = _similarity(nominal.centres[keep], measured_t[keep])
    residual = torch.linalg.vector_norm(measured_t - _apply(params, nominal.centres), dim=1)
    flags = flags | torch.where((flags == 0) & ~keep, RESIDUAL, 0)
    a, b, ty, tx = params.tolist()
    return SubImageFit(
        nominal=nominal.centres.clone(),
        measured=measured_t,
        residual=residual,
        light=light_t,
        flags=flags,
        scale=math.hypot(a, b),
        rotation=math.atan2(b, a),
        shift=(ty, tx),
    )
