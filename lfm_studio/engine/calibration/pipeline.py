"""Calibrate an instrument from a radiometry (and dark) frame; correct and rectify its raw frames.

``calibrate`` runs: input checks -> dark subtraction (the dark frame pixel by pixel, else the
camera baseline) -> defective pixels (hot in the dark and radiometry frames, dead in the
radiometry frame) replaced by their 3 x 3 median ->
conventional LFM: Fourier lattice, centroid refinement, flat-field envelope, a second
refinement on the flat-fielded frame (vignetting no longer pulls the centroids) ->
Fourier LFM: sub-image centres registered to the design, then a flat field per sub-image.
``rectify_frame`` applies a calibration to a raw frame so that the design's projector can
reconstruct it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import torch

from lfm_studio.engine.calibration import defects as defect_pixels
from lfm_studio.engine.calibration.checks import as_frame, check_frames, check_pitch
from lfm_studio.engine.calibration.corrections import FrameCorrections, frame_corrections
from lfm_studio.engine.calibration.flat_field import fit_envelope, flat_field
from lfm_studio.engine.calibration.grid_fit import DIM, LatticeFit, refine_lattice
from lfm_studio.engine.calibration.grid_fourier import fourier_lattice
from lfm_studio.engine.calibration.nominal import nominal_grid, nominal_sub_images
from lfm_studio.engine.calibration.record import Calibration
from lfm_studio.engine.calibration.rectify import lenslet_block, rectify
from lfm_studio.engine.calibration.sub_image_flat import fit_sub_image_flat
from lfm_studio.engine.calibration.sub_images import fit_sub_images
from lfm_studio.engine.design import Design
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint
from lfm_studio.engine.systems.kinds import kind_of

_STEPS = 5
HOT_RELATIVE = 0.25  # radiometry: a hot pixel is 25 % above its brightest neighbour


def calibrate(
    radiometry: object,
    design: Design,
    *,
    dark: object | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> Calibration:
    """Measure the lenslet grid (or sub-image centres) and the corrections of an instrument.

    Parameters
    ----------
    radiometry : (Y, X) frame of a uniform fluorescent slide, ADU (tensor or array).
    design : the nominal design (conventional: regular MLA; Fourier: any lenslet list).
    dark : optional (Y, X) frame with the light blocked, same exposure, ADU.
    progress, cancel : see :mod:`lfm_studio.engine.progress`.
    """
    frame = as_frame("radiometry", radiometry)
    dark_frame = None if dark is None else as_frame("dark", dark)
    check_frames(frame, dark_frame, design.camera)
    checkpoint(cancel, progress, 0, _STEPS, "defective pixels")
    dark_level = float(dark_frame.median()) if dark_frame is not None else design.camera.baseline_adu
    lit = defect_pixels.subtract_dark(frame, dark_frame if dark_frame is not None else dark_level)
    bad = defect_pixels.hot_pixels(lit, relative=HOT_RELATIVE) | defect_pixels.dead_pixels(lit)
    if dark_frame is not None:
        bad |= defect_pixels.hot_pixels(dark_frame)
    image = defect_pixels.replace_defects(lit, bad)
    shape = (int(frame.shape[0]), int(frame.shape[1]))
    calibration = partial(
        Calibration,
        frame_shape=shape,
        design=design.model_dump(mode="json"),
        dark_level=dark_level,
        dark_frame=None if dark_frame is None else dark_frame.to(torch.float32),
        defects=torch.nonzero(bad),
    )
    if kind_of(design).mla_at_pupil:  # one sub-image per lenslet: fit their centres
        checkpoint(cancel, progress, 1, _STEPS, "sub-image centres")
        nominal_subs = nominal_sub_images(design, shape)
        fit = fit_sub_images(image, nominal_subs)
        checkpoint(cancel, progress, 3, _STEPS, "flat field per sub-image")
        flat = fit_sub_image_flat(image, fit.measured, fit.flags, nominal_subs.diameter)
        checkpoint(cancel, progress, _STEPS, _STEPS, "done")
        return calibration(
            kind=design.kind,
            envelope=None,
            pixels_per_lenslet=None,
            block=None,
            grid=None,
            sub_images=fit,
            sub_image_flat=flat,
        )
    nominal = nominal_grid(design)
    checkpoint(cancel, progress, 1, _STEPS, "lattice from Fourier peaks")
    coarse = fourier_lattice(image, nominal.pitch)
    check_pitch(coarse.pitch, nominal.pitch)
    checkpoint(cancel, progress, 2, _STEPS, "lenslet centroids")
    grid = refine_lattice(image, coarse, disk_diameter=nominal.disk_diameter)
    checkpoint(cancel, progress, 3, _STEPS, "flat field")
    envelope = fit_envelope(grid.measured[grid.used], grid.mass[grid.used], shape)
    checkpoint(cancel, progress, 4, _STEPS, "lenslet centroids (flat fielded)")
    grid = refine_lattice(flat_field(image, envelope), grid.lattice, disk_diameter=nominal.disk_diameter)
    check_pitch(grid.lattice.pitch, nominal.pitch)
    checkpoint(cancel, progress, _STEPS, _STEPS, "done")
    return calibration(
        kind=design.kind,
        envelope=envelope,
        pixels_per_lenslet=nominal.pixels_per_lenslet,
        block=lenslet_block(grid.lattice, shape, lit=_lit(grid)),
        grid=grid,
        sub_images=None,
    )


def _lit(grid: LatticeFit) -> set[tuple[int, int]]:
    """Indices of the lenslets that are not dim (the field of view; dust specks count as lit)."""
    return {
        tuple(ij)
        for ij, flag in zip(grid.indices.tolist(), grid.flags.tolist(), strict=True)
        if not flag & DIM
    }


def correct_frame(raw: object, calibration: Calibration) -> torch.Tensor:
    """``raw`` (Y, X) minus the dark frame (or level), defects replaced, divided by the flat field
    (the envelope of a conventional LFM, the per-sub-image gains of a Fourier LFM); float64."""
    return frame_corrections(calibration).apply(raw)


@dataclass(frozen=True)
class FrameRectifier:
    """:func:`rectify_frame` for one calibration, with its corrections prepared once: a video's
    frames are rectified one at a time (each may fail on its own) without preparing the defect
    mask, dark frame and flat-field map again per frame. Call it on one raw frame ``(Y, X)``."""

    calibration: Calibration
    corrections: FrameCorrections
    block: tuple[int, int, int, int] | None

    @property
    def output_shape(self) -> tuple[int, int]:
        """``(Y, X)`` pixels of a rectified frame: the lenslet block times ``pixels_per_lenslet``
        (conventional LFM), else the raw frame's shape."""
        n = self.calibration.pixels_per_lenslet
        if self.calibration.grid is None or self.block is None or n is None:
            rows, columns = self.corrections.frame_shape
            return (int(rows), int(columns))
        return (self.block[1] * n, self.block[3] * n)

    def __call__(self, frame: object) -> torch.Tensor:
        image = self.corrections.apply(frame)
        grid, n = self.calibration.grid, self.calibration.pixels_per_lenslet
        if grid is None or self.block is None or n is None:  # Fourier LFM: corrected only
            return image
        return rectify(image, grid.lattice, n, self.block)


def frame_rectifier(calibration: Calibration, *, lenslets: tuple[int, int] | None = None) -> FrameRectifier:
    """The :class:`FrameRectifier` of ``calibration`` (``lenslets``: as in :func:`rectify_frame`)."""
    corrections = frame_corrections(calibration)  # mask, dark frame, flat-field map
    grid, n = calibration.grid, calibration.pixels_per_lenslet
    block = None
    if grid is not None:
        block = (
            calibration.block
            if lenslets is None
            else lenslet_block(grid.lattice, calibration.frame_shape, lenslets)
        )
        if block is None or n is None:
            raise ValueError("a conventional calibration needs its lenslet block and pixels_per_lenslet.")
    return FrameRectifier(calibration, corrections, block)


def rectified_shape_fix(
    calibration: Calibration, sensor: tuple[int, ...], lenslets_option: str = "lenslets=({ny}, {nx})"
) -> str:
    """How to make frames rectified with ``calibration`` and a PSF imaging ``sensor`` pixels agree:
    the PSF of the rectified design, or (conventional LFM, when ``sensor`` is whole lenslets) the
    lenslet block that matches it, written as ``lenslets_option`` (e.g. ``"--lenslets {ny} {nx}"``)."""
    fix = (
        "Fix: simulate the PSF for these frames ('lfm-studio calibrate --radiometry ... --design-out "
        "rectified.json', then 'lfm-studio simulate rectified.json --out psf.tif')"
    )
    n = calibration.pixels_per_lenslet
    if calibration.grid is not None and n and sensor[0] % n == 0 and sensor[1] % n == 0:
        fix += (
            ", or pass " + lenslets_option.format(ny=sensor[0] // n, nx=sensor[1] // n) + " to match this PSF"
        )
    return fix + "."


def rectify_frame(
    raw: object, calibration: Calibration, *, lenslets: tuple[int, int] | None = None
) -> torch.Tensor:
    """A raw camera frame ready for the design's projector.

    Conventional LFM: corrected (:func:`correct_frame`) and resampled onto
    ``pixels_per_lenslet`` pixels per lenslet (:mod:`.rectify`), shape ``(ni n, nj n)``:
    the calibration's lenslet block, or ``lenslets=(ny, nx)`` centred on the lenslet nearest
    the frame centre. Fourier LFM: corrected only; the measured sub-image centres enter
    through :func:`~lfm_studio.engine.calibration.fitted_design.fitted_design` instead.
    A time series ``(T, Y, X)`` is rectified frame by frame into ``(T, ...)``; the defect mask,
    dark frame and flat-field map are prepared once for the series (:class:`FrameRectifier`).
    """
    frames = torch.as_tensor(raw)
    one = frame_rectifier(calibration, lenslets=lenslets)
    return torch.stack([one(frame) for frame in frames]) if frames.ndim == 3 else one(raw)
