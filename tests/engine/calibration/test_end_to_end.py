"""Issue 21 end to end: beads seen through a misaligned raw geometry, calibrated, rectified and
reconstructed, reach the aligned case's correlation with the truth (within 0.05).

The forward model (``lfm_10x_na03`` on 8 x 8 lenslets, 3 depths) renders the bead image and
the radiometry frame (a uniform slab at focus) on its own lattice of 19 px per lenslet;
:func:`unrectify` shows both through a raw camera with 19.37 x 19.31 px lenslets, a 1.5 deg
rotation and an offset; then vignetting, Poisson and read noise, a dark offset and 0.1 %
hot pixels are added (:mod:`lfm_studio.engine.calibration.synthetic_scene`). Only engine
functions are used. Floor: reconstructing a plain crop of
the raw frame (no calibration) must score far lower, so the check can fail.
"""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.calibration import calibrate, rectify_frame
from lfm_studio.engine.calibration.synthetic_scene import BASELINE_ADU, misaligned_bead_scene
from lfm_studio.engine.image_quality import ncc
from lfm_studio.engine.reconstruct.dispatch import reconstruct_frame
from lfm_studio.engine.simulation import imaging_setup

LENSLETS = 8


def _correlation(estimate: torch.Tensor, truth: torch.Tensor) -> float:
    return float(ncc(truth, estimate))  # Pearson; 0 for the all-zero and constant volumes


@pytest.fixture(scope="module")
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_calibrated_misaligned_frame_reconstructs_like_the_aligned_one(_one_thread):
    scene = misaligned_bead_scene(LENSLETS)
    projector = imaging_setup(scene.stack).projector
    truth = scene.truth
    aligned_score = _correlation(
        reconstruct_frame(projector, (scene.aligned - BASELINE_ADU).float().clamp_min(0.0)), truth
    )
    # the warp conserves light: the raw frame holds the aligned frame's photons (Poisson noise aside)
    raw_light = float((scene.raw - BASELINE_ADU).sum()) / float((scene.aligned - BASELINE_ADU).sum())
    assert raw_light == pytest.approx(1.0, abs=0.2)  # 20 % vignetting at the corners, hot pixels

    calibration = calibrate(scene.radiometry, scene.nominal, dark=scene.dark)
    fitted = calibration.grid.lattice
    assert fitted.pitch == pytest.approx(scene.lattice.pitch, abs=0.01)
    assert math.degrees(fitted.rotation) == pytest.approx(1.5, abs=0.02)

    block = (-(LENSLETS // 2), LENSLETS, -(LENSLETS // 2), LENSLETS)
    assert calibration.block == block  # the default block: the lit lenslets, not the dark rim around them
    rectified = rectify_frame(scene.raw, calibration)
    assert rectified.shape == scene.aligned.shape
    calibrated_score = _correlation(reconstruct_frame(projector, rectified.float().clamp_min(0.0)), truth)
    floor_score = _correlation(
        reconstruct_frame(projector, (scene.crop - BASELINE_ADU).float().clamp_min(0.0)), truth
    )

    assert aligned_score > 0.8  # measured 0.90
    assert calibrated_score >= aligned_score - 0.05  # measured 0.89
    assert floor_score < 0.3  # measured 0.00: without calibration the beads are lost
