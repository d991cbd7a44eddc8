"""How much of a Fourier design a sensor crop sees, and the smallest crop that sees enough.

A study simulates each candidate's PSF on a ``crop x crop`` px square of the sensor about the
axis (:class:`~lfm_studio.engine.optimize.candidate.EvaluationSettings`). A Fourier LFM images an
in-focus point onto one spot per lenslet, at the lenslet's centre projected on the sensor (the
sub-image centre, :func:`~lfm_studio.engine.calibration.nominal.nominal_sub_images`); a crop that
holds none of these spots keeps only the diffraction tails of the PSF. On ``xlfm_cong2017`` (27
lenslets, the innermost three centred 195 px off the axis) the default 256 px crop holds none:
5e-5 of the on-axis light, against 0.10 at 512 px, and the task score ``task_ncc`` of the preset
(5 depths over +-40 um) is 0.05 at 256 px, 0.49 at 384, 0.76 at 512 and 0.87 at 768.

:func:`auto_crop` picks the smallest crop, in steps of 128 px from 256 (the old fixed default,
so designs that had enough views there keep it), that holds the sub-image centres of at least
:data:`MIN_VIEWS` lenslets (all of them when the design has fewer): parallax between views is
what measures depth.
"""

from __future__ import annotations

from dataclasses import dataclass

from lfm_studio.engine.calibration.nominal import nominal_sub_images
from lfm_studio.engine.design import Design
from lfm_studio.engine.systems.kinds import kind_of

MIN_VIEWS = 3
"""Sub-image centres a crop must hold (or all the lenslets of a design with fewer)."""

CROP_STEP = 128
"""Granularity of :func:`auto_crop`, px."""

MIN_CROP = 256
"""Smallest crop :func:`auto_crop` returns, px (the fixed default before it)."""


@dataclass(frozen=True)
class CropViews:
    """What a crop of a Fourier design holds.

    crop : the crop in px (None: the whole sensor).
    views : lenslets whose sub-image centre (on-axis spot) lies on the crop.
    lenslets : the design's lenslet count.
    needed : views a useful crop holds (:data:`MIN_VIEWS`, at most ``lenslets``).
    """

    crop: int | None
    views: int
    lenslets: int
    needed: int

    @property
    def enough(self) -> bool:
        return self.views >= self.needed

    def describe(self) -> str:
        where = "the whole sensor" if self.crop is None else f"the {self.crop} px crop"
        return f"{where} holds {self.views} of the {self.lenslets} sub-image centres"


def crop_views(design: Design, crop: int | None) -> CropViews | None:
    """The sub-image centres of a Fourier ``design`` on a ``crop`` px crop about the axis (None:
    the whole sensor); None for a design without sub-images at the pupil (conventional LFM)."""
    if not kind_of(design).mla_at_pupil:
        return None
    ny, nx = design.camera.pixel_count
    shape = (ny, nx) if crop is None else (min(crop, ny), min(crop, nx))
    centres = nominal_sub_images(design, shape).centres
    # A centre is on the crop when the pixel it falls in is (pixel k covers [k - 0.5, k + 0.5)).
    rows, cols = centres[:, 0], centres[:, 1]
    inside = (rows >= -0.5) & (rows < shape[0] - 0.5) & (cols >= -0.5) & (cols < shape[1] - 0.5)
    lenslets = len(design.mla.lenslets)
    return CropViews(crop, int(inside.sum()), lenslets, min(MIN_VIEWS, lenslets))


def auto_crop(design: Design) -> int | None:
    """The smallest crop (px, a multiple of :data:`CROP_STEP`, at least :data:`MIN_CROP`) holding
    enough sub-image centres (:func:`crop_views`); None (the whole sensor) when only the whole
    sensor does or the sensor is not larger than that crop. Conventional designs: :data:`MIN_CROP`
    (their crop keeps whole lenslets about the axis)."""
    ny, nx = design.camera.pixel_count
    if crop_views(design, None) is None:
        return MIN_CROP
    crop = MIN_CROP
    while crop < max(ny, nx):
        found = crop_views(design, crop)
        if found is not None and found.enough:
            return crop
        crop += CROP_STEP
    return None
