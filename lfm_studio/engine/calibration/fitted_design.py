"""A design fitted to a calibration: the nominal optics with the measured MLA geometry.

- Conventional LFM: the MLA pitch becomes the measured pitch (the mean of the two axes,
  in micrometres on the sensor) and ``offset_um`` the measured lattice offset from the
  optical axis, taken at the sensor's centre pixel ``(Y // 2, X // 2)``; the camera gets
  the calibrated frame's pixel count. The rotation (and any per-axis difference) is
  removed by rectification and recorded in ``assumed``.
- Fourier LFM: each lenslet centre becomes its measured sub-image centre (the chief ray
  of an on-axis point crosses the sensor at the lenslet centre). Touching apertures that the
  measurement puts a little closer are reduced just enough not to overlap (noted in ``assumed``).
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.calibration.record import Calibration
from lfm_studio.engine.design import Design, LensletSpec, MLASpec, RegularMLASpec
from lfm_studio.engine.design.lenslet import overlap_depth_um
from lfm_studio.engine.systems.kinds import kind_named, kind_of


def _axis(calibration: Calibration) -> tuple[float, float]:
    ny, nx = calibration.frame_shape
    return float(ny // 2), float(nx // 2)


def _moved(
    lenslets: tuple[LensletSpec, ...], centres: list[tuple[float, float]], shrink: float
) -> tuple[LensletSpec, ...]:
    """``lenslets`` at new ``centres`` (x, y) um, apertures ``shrink`` um smaller."""
    return tuple(
        LensletSpec(
            center_um=centre,
            aperture_diameter_um=lens.aperture_diameter_um - shrink,
            focal_length_mm=lens.focal_length_mm,
            shape=lens.shape,
        )
        for lens, centre in zip(lenslets, centres, strict=True)
    )


def _regular_mla(design: Design) -> RegularMLASpec:
    """The design's MLA, which a fitted lattice describes: it must be a regular array."""
    if not isinstance(design.mla, RegularMLASpec):
        raise ValueError(
            f"a lenslet lattice calibration needs a regular MLA (layout 'regular'); got layout "
            f"{design.mla.layout!r}. Fix: use the design the calibration was made with."
        )
    return design.mla


def mla_at_centres(
    design: Design, centres_yx: torch.Tensor, frame_shape: tuple[int, int]
) -> tuple[MLASpec, str]:
    """A Fourier ``design``'s MLA with each lenslet at a sub-image centre ``centres_yx`` (L, 2) px.

    Centres are taken on a frame of ``frame_shape`` whose optical axis is pixel ``(Y // 2, X // 2)``.
    Returns the MLA and the end of a note for ``assumed`` (". " or the aperture reduction that
    keeps touching apertures from overlapping).
    """
    pixel_um = design.camera.pixel_pitch_um
    axis_y, axis_x = float(frame_shape[0] // 2), float(frame_shape[1] // 2)
    centres = [((x - axis_x) * pixel_um, (y - axis_y) * pixel_um) for y, x in centres_yx.tolist()]
    lenslets = _moved(design.mla.lenslets, centres, shrink=0.0)
    shrink = max(
        (overlap_depth_um(a, b) for i, a in enumerate(lenslets) for b in lenslets[i + 1 :]), default=0.0
    )
    if shrink > 0:  # touching apertures measured a little closer: keep them touching
        lenslets = _moved(design.mla.lenslets, centres, shrink=shrink + 1e-4)
    mla = MLASpec(lenslets=lenslets, array_aperture_diameter_um=design.mla.array_aperture_diameter_um)
    return mla, (
        f"; apertures reduced by {shrink:.4g} um so that they do not overlap." if shrink > 0 else "."
    )


def nominal_design(calibration: Calibration) -> Design:
    """The nominal design the calibration was made with (stored in it)."""
    return Design.model_validate(calibration.design)


def fitted_design(design: Design | None, calibration: Calibration) -> Design:
    """``design`` (default: the calibration's nominal one) with the MLA geometry measured by ``calibration``."""
    design = nominal_design(calibration) if design is None else design
    mine, theirs = kind_of(design), kind_named(calibration.kind)
    if mine is not theirs:
        raise ValueError(
            f"the design is a {mine.title} but the calibration was made for a {theirs.title}. "
            "Fix: use the design the calibration was made with."
        )
    pixel_um = design.camera.pixel_pitch_um
    axis_y, axis_x = _axis(calibration)
    camera = design.camera.model_copy(update={"pixel_count": tuple(calibration.frame_shape)})
    camera = type(design.camera).model_validate(camera.model_dump())
    if calibration.grid is not None:
        lattice = calibration.grid.lattice
        pitch_px = math.sqrt(lattice.pitch[0] * lattice.pitch[1])
        oy, ox = lattice.origin
        shape = _regular_mla(design).shape
        half = [0.5 if n % 2 == 0 else 0.0 for n in shape]  # an even array is centred between sites
        offset_y = (
            oy + half[0] * lattice.row_vector[0] + half[1] * lattice.col_vector[0] - axis_y
        ) * pixel_um
        offset_x = (
            ox + half[0] * lattice.row_vector[1] + half[1] * lattice.col_vector[1] - axis_x
        ) * pixel_um
        mla = design.mla.model_copy(
            update={"pitch_um": pitch_px * pixel_um, "offset_um": (offset_x, offset_y)}
        )
        mla = type(design.mla).model_validate(mla.model_dump())
        note = (
            f"calibrated: lattice pitch {lattice.pitch[0]:.4f} x {lattice.pitch[1]:.4f} px, rotation "
            f"{math.degrees(lattice.rotation):.4f} deg (removed by rectification), origin "
            f"({oy:.3f}, {ox:.3f}) px."
        )
    else:
        fit = calibration.sub_images
        if fit is None:  # excluded by Calibration.__post_init__
            raise ValueError("a Fourier calibration needs its sub-image fit.")
        mla, moved = mla_at_centres(design, fit.measured, calibration.frame_shape)
        note = (
            f"calibrated: {len(mla.lenslets)} lenslet centres from their measured sub-images (similarity to "
            f"the nominal layout: scale {fit.scale:.5f}, rotation {math.degrees(fit.rotation):.4f} deg){moved}"
        )
    return design.updated(
        name=f"{design.name} (calibrated)", mla=mla, camera=camera, assumed=(*design.assumed, note)
    )


def rectified_design(
    design: Design | None, calibration: Calibration, *, lenslets: tuple[int, int] | None = None
) -> Design:
    """The design whose projector images exactly what :func:`rectify_frame` makes of a raw frame.

    Conventional LFM only: ``design`` (default: the calibration's nominal one) on a sensor just
    large enough for the rectified block of ``ni x nj`` lenslets (the calibration's block, or
    ``lenslets=(ny, nx)``), so that a PSF simulated from it (``lfm-studio simulate``) has the
    rectified frame's shape ``(ni n, nj n)``, ``n`` = ``pixels_per_lenslet``. The measured
    pitch, rotation and offset are removed by rectification (recorded in ``assumed``).
    """
    design = nominal_design(calibration) if design is None else design
    if calibration.grid is None or calibration.block is None:
        raise ValueError(
            "rectified_design needs a conventional calibration; a Fourier LFM's raw frame is not "
            "rectified. Fix: use fitted_design(design, calibration) for a Fourier LFM."
        )
    if kind_of(design).mla_at_pupil:
        raise ValueError(
            f"the design is a {kind_of(design).title} but the calibration was made for a conventional LFM. "
            "Fix: use the design the calibration was made with."
        )
    ni, nj = (calibration.block[1], calibration.block[3]) if lenslets is None else lenslets
    regular = _regular_mla(design)
    ratio = regular.pitch_um / design.camera.pixel_pitch_um  # lenslet pitch on the sensor, px
    # The projector images int(count / ratio) lenslets: half a lenslet of margin keeps rounding away.
    count = (math.ceil((ni + 0.5) * ratio), math.ceil((nj + 0.5) * ratio))
    mla = regular.model_copy(update={"shape": (ni, nj), "offset_um": (0.0, 0.0)})
    camera = design.camera.model_copy(update={"pixel_count": count})
    lattice = calibration.grid.lattice
    note = (
        f"rectified: {ni} x {nj} lenslets of {calibration.pixels_per_lenslet} px from a raw lattice of "
        f"{lattice.pitch[0]:.4f} x {lattice.pitch[1]:.4f} px, rotation {math.degrees(lattice.rotation):.4f} deg."
    )
    return design.updated(
        name=f"{design.name} (rectified)",
        mla=type(design.mla).model_validate(mla.model_dump()),
        camera=type(design.camera).model_validate(camera.model_dump()),
        assumed=(*design.assumed, note),
    )
