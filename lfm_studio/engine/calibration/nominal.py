"""What a design predicts a radiometry frame looks like: lenslet pitch, disk size, sub-image centres.

Frame coordinates follow :mod:`~lfm_studio.engine.calibration.lattice` (pixel centres at
integers, points ``(y, x)``); the optical axis falls on pixel ``(Y // 2, X // 2)`` of the
camera (the engine's grid convention), rows increasing with ``y``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lfm_studio.engine.design import Design
from lfm_studio.engine.systems.from_design import conventional_system_of
from lfm_studio.engine.systems.kinds import kind_of


@dataclass(frozen=True)
class NominalGrid:
    """A conventional LFM's expected lenslet grid on the camera.

    Attributes
    ----------
    pitch : lenslet pitch on the sensor, px (``pitch_um / pixel_pitch_um``).
    disk_diameter : diameter of the back-aperture disk behind each lenslet, px (at most the pitch).
    pixels_per_lenslet : odd rectified pixels per lenslet, as the design's projector uses (the pitch
        rounded to the nearest odd integer).
    """

    pitch: float
    disk_diameter: float
    pixels_per_lenslet: int


@dataclass(frozen=True)
class NominalSubImages:
    """A Fourier LFM's expected sub-images on the camera.

    Attributes
    ----------
    centres : (L, 2) float64 (y, x) px, one per lenslet of the design, in design order.
    diameter : expected sub-image diameter, px.
    """

    centres: torch.Tensor
    diameter: float


def nominal_grid(design: Design) -> NominalGrid:
    """The lenslet grid a conventional ``design`` predicts on its camera."""
    if kind_of(design).mla_at_pupil:
        raise ValueError(
            f"nominal_grid needs a conventional design (MLA at the image plane); got a {kind_of(design).title}."
        )
    pitch_um = getattr(design.mla, "pitch_um", None)
    if pitch_um is None:
        raise ValueError(
            "a conventional calibration needs a regular MLA (layout 'regular') with pitch_um. "
            "Fix: give the design a RegularMLASpec."
        )
    pitch = pitch_um / design.camera.pixel_pitch_um
    radius = design.sub_image_radius or 0.5 * pitch_um * 1e-6
    disk = min(2.0 * radius / design.camera.pixel_pitch, pitch)
    odd = conventional_system_of(design, lenslets=(1, 1)).pixels_per_lenslet  # the projector's own choice
    return NominalGrid(pitch=pitch, disk_diameter=disk, pixels_per_lenslet=odd)


def nominal_sub_images(design: Design, frame_shape: tuple[int, int]) -> NominalSubImages:
    """The sub-image centres and diameter a Fourier ``design`` predicts on a frame of ``frame_shape``."""
    if not kind_of(design).mla_at_pupil:
        raise ValueError(
            f"nominal_sub_images needs a Fourier design (MLA at the pupil); got a {kind_of(design).title}."
        )
    ny, nx = frame_shape
    pitch = design.camera.pixel_pitch_um
    centres = torch.tensor(
        [
            [ny // 2 + lens.center_um[1] / pitch, nx // 2 + lens.center_um[0] / pitch]
            for lens in design.mla.lenslets
        ],
        dtype=torch.float64,
    )
    radius = design.sub_image_radius
    if radius is None:  # unlimited field: the lenslet aperture bounds the sub-image
        radius = 0.5 * min(lens.aperture_diameter for lens in design.mla.lenslets)
    return NominalSubImages(centres=centres, diameter=2.0 * radius / design.camera.pixel_pitch)


def min_spacing(centres: torch.Tensor) -> float:
    """Smallest distance between two of ``centres`` (L, 2), px (inf for one centre)."""
    if centres.shape[0] < 2:
        return math.inf
    d = torch.cdist(centres, centres)
    d.fill_diagonal_(math.inf)
    return float(d.min())
