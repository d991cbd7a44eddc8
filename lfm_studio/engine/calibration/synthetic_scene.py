"""A bead volume seen through a misaligned raw camera, with its radiometry and dark frames (tests, demos).

The forward model of ``lfm_10x_na03`` (``lenslets x lenslets`` lenslets of 19 px, 3 depths)
renders six beads and a uniform slab at focus on its own lattice; :func:`unrectify` shows both
through a raw camera with 19.37 x 19.31 px lenslets, a 1.5 deg rotation and an offset; then
20 % vignetting, Poisson and read noise (1.5 e-), a 100 ADU dark offset and 0.1 % hot pixels
(3000 ADU) are added (gain 1 ADU per electron). The same beads imaged on the model's own
lattice (no hot pixels, no vignetting) are the aligned reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lfm_studio.engine.calibration.lattice import LensletLattice
from lfm_studio.engine.calibration.rectify import unrectify
from lfm_studio.engine.calibration.synthetic import expose, radial_vignetting
from lfm_studio.engine.design import Design, load_preset
from lfm_studio.engine.phantoms import beads
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.simulation import imaging_setup, simulate_psf

BASELINE_ADU = 100.0
RAW_SHAPE = (188, 192)


@dataclass(frozen=True)
class MisalignedScene:
    """Frames (ADU, float64) and truth of :func:`misaligned_bead_scene`.

    Attributes
    ----------
    nominal : the instrument's nominal design on the raw camera (what ``calibrate`` gets).
    stack : the PSF stack of the model's lattice (aligned design); its projector images ``aligned``.
    truth : (Z, Y, X) bead volume, photons scaled by ``scale``.
    raw, radiometry, dark : raw camera frames, ``RAW_SHAPE``.
    aligned : the beads on the model's lattice, same camera noise, no hot pixels or vignetting.
    crop : ``raw`` cropped to the aligned frame's shape around the centre (the uncalibrated floor).
    lattice : the raw camera's true lenslet lattice.
    scale : photons per unit of ``truth`` in the frames.
    """

    nominal: Design
    stack: PSFStack
    truth: torch.Tensor
    raw: torch.Tensor
    radiometry: torch.Tensor
    dark: torch.Tensor
    aligned: torch.Tensor
    crop: torch.Tensor
    lattice: LensletLattice
    scale: float


def _camera(image: torch.Tensor, *, seed: int, hot_fraction: float, vignetting: torch.Tensor | float = 1.0):
    frame, dark, _ = expose(
        image.double() * vignetting,
        baseline_adu=BASELINE_ADU,
        read_noise_e=1.5,
        gain_adu_per_e=1.0,
        hot_fraction=hot_fraction,
        hot_adu=3000.0,
        seed=seed,
    )
    return frame, dark


def misaligned_bead_scene(lenslets: int = 8, photons: float = 2e6) -> MisalignedScene:
    """The scene of the module docstring; ``photons`` in the whole bead image."""
    base = load_preset("lfm_10x_na03")
    side = lenslets * 19 + 2
    design = base.updated(
        camera={**base.camera.model_dump(), "pixel_count": (side, side)},
        depths={"depth_range_um": (-20.0, 20.0), "depth_step_um": 20.0},
    )
    stack = simulate_psf(design)
    setup = imaging_setup(stack)
    projector = setup.projector
    truth = beads(
        setup.volume_shape, count=6, voxel_size=setup.voxel_size, seed=3, intensity=1.0, margin=0.0
    ).data
    image = projector.forward(truth.float()).clamp_min(0.0).double()
    slab = torch.zeros(setup.volume_shape)
    slab[setup.volume_shape[0] // 2] = 1.0
    radiometry_model = projector.forward(slab).clamp_min(0.0).double()
    scale = photons / float(image.sum())
    lattice = LensletLattice.from_geometry(
        (19.37, 19.31), math.radians(1.5), ((RAW_SHAPE[0] - 1) / 2 + 2.3, (RAW_SHAPE[1] - 1) / 2 - 3.1)
    )
    block = (-(lenslets // 2), lenslets, -(lenslets // 2), lenslets)
    vignetting = radial_vignetting(RAW_SHAPE, 0.2)
    raw_model = unrectify(image, lattice, block, RAW_SHAPE) * scale
    raw, _ = _camera(raw_model, seed=2, hot_fraction=1e-3, vignetting=vignetting)
    radiometry_raw = unrectify(radiometry_model, lattice, block, RAW_SHAPE)
    radiometry, dark = _camera(
        radiometry_raw * (2000.0 / float(radiometry_raw.max())),
        seed=3,
        hot_fraction=1e-3,
        vignetting=vignetting,
    )
    aligned, _ = _camera(image * scale, seed=1, hot_fraction=0.0)
    top, left = ((r - s) // 2 for r, s in zip(RAW_SHAPE, image.shape, strict=True))
    crop = raw[top : top + image.shape[0], left : left + image.shape[1]]
    nominal = design.updated(camera={**design.camera.model_dump(), "pixel_count": RAW_SHAPE})
    return MisalignedScene(nominal, stack, truth, raw, radiometry, dark, aligned, crop, lattice, scale)
