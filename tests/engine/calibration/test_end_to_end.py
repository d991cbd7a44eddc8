"""Issue 21 end to end: beads seen through a misaligned raw geometry, calibrated, rectified and
reconstructed, reach the aligned case's correlation with the truth (within 0.05).

The forward model (``lfm_10x_na03`` on 8 x 8 lenslets, 3 depths) renders the bead image and
the radiometry frame (a uniform slab at focus) on its own lattice of 19 px per lenslet;
:func:`unrectify` shows both through a raw camera with 19.37 x 19.31 px lenslets, a 1.5 deg
rotation and an offset; then vignetting, Poisson and read noise, a dark offset and 0.1 %
hot pixels are added. Only engine functions are used. Floor: reconstructing a plain crop of
the raw frame (no calibration) must score far lower, so the check can fail.
"""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.calibration import LensletLattice, calibrate, rectify_frame
from lfm_studio.engine.calibration.rectify import unrectify
from lfm_studio.engine.calibration.synthetic import expose, radial_vignetting
from lfm_studio.engine.design import load_preset
from lfm_studio.engine.phantoms import beads
from lfm_studio.engine.reconstruct.dispatch import reconstruct_frame
from lfm_studio.engine.simulation import imaging_setup, simulate_psf

LENSLETS = 8
RAW_SHAPE = (188, 192)
PHOTONS = 2e6
BASELINE = 100.0


def _camera(image: torch.Tensor, *, seed: int, hot_fraction: float, vignetting: torch.Tensor | float = 1.0):
    frame, dark, _ = expose(
        image.double() * vignetting,
        baseline_adu=BASELINE,
        read_noise_e=1.5,
        gain_adu_per_e=1.0,
        hot_fraction=hot_fraction,
        hot_adu=3000.0,
        seed=seed,
    )
    return frame, dark


def _correlation(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a.double().flatten(), b.double().flatten()
    a, b = a - a.mean(), b - b.mean()
    return float(a @ b / (a.norm() * b.norm()))


@pytest.fixture(scope="module")
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_calibrated_misaligned_frame_reconstructs_like_the_aligned_one(_one_thread):
    base = load_preset("lfm_10x_na03")
    side = LENSLETS * 19 + 2
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
    slab[len(stack.depths) // 2] = 1.0
    radiometry_model = projector.forward(slab).clamp_min(0.0).double()
    scale = PHOTONS / float(image.sum())

    # Aligned: the model's own lattice, no hot pixels, no vignetting.
    aligned, _ = _camera(image * scale, seed=1, hot_fraction=0.0)
    aligned_score = _correlation(
        reconstruct_frame(projector, (aligned - BASELINE).float().clamp_min(0.0)), truth
    )

    # Misaligned raw camera.
    lattice = LensletLattice.from_geometry(
        (19.37, 19.31), math.radians(1.5), ((RAW_SHAPE[0] - 1) / 2 + 2.3, (RAW_SHAPE[1] - 1) / 2 - 3.1)
    )
    block = (-(LENSLETS // 2), LENSLETS, -(LENSLETS // 2), LENSLETS)
    vignetting = radial_vignetting(RAW_SHAPE, 0.2)
    raw_model = unrectify(image, lattice, block, RAW_SHAPE)
    assert float(raw_model.sum()) == pytest.approx(float(image.sum()), rel=1e-9)  # the warp conserves light
    raw, _ = _camera(raw_model * scale, seed=2, hot_fraction=1e-3, vignetting=vignetting)
    radiometry_raw = unrectify(radiometry_model, lattice, block, RAW_SHAPE)
    radiometry, dark = _camera(
        radiometry_raw * (2000.0 / float(radiometry_raw.max())),
        seed=3,
        hot_fraction=1e-3,
        vignetting=vignetting,
    )
    raw_design = design.updated(camera={**design.camera.model_dump(), "pixel_count": RAW_SHAPE})
    calibration = calibrate(radiometry, raw_design, dark=dark)
    fitted = calibration.grid.lattice
    assert fitted.pitch == pytest.approx(lattice.pitch, abs=0.01)
    assert math.degrees(fitted.rotation) == pytest.approx(1.5, abs=0.02)

    assert calibration.block == block  # the default block: the lit lenslets, not the dark rim around them
    rectified = rectify_frame(raw, calibration)
    assert rectified.shape == image.shape
    calibrated_score = _correlation(reconstruct_frame(projector, rectified.float().clamp_min(0.0)), truth)

    top, left = ((r - s) // 2 for r, s in zip(RAW_SHAPE, image.shape, strict=True))
    crop = (raw - BASELINE)[top : top + image.shape[0], left : left + image.shape[1]]
    floor_score = _correlation(reconstruct_frame(projector, crop.float().clamp_min(0.0)), truth)

    assert aligned_score > 0.8  # measured 0.90
    assert calibrated_score >= aligned_score - 0.05  # measured 0.89
    assert floor_score < 0.3  # measured 0.00: without calibration the beads are lost
