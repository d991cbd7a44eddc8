"""A bead z-scan registered to a Fourier calibration's optical axis (sub-pixel), and its refusals."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from lfm_studio.engine.bead_psf import fourier_shift
from lfm_studio.engine.calibration import calibrate, fitted_design
from lfm_studio.engine.calibration.bead_scan import register_bead_psf
from lfm_studio.engine.calibration.synthetic_fourier_scene import misaligned_fourier_scene
from lfm_studio.engine.image_quality import ncc
from lfm_studio.engine.simulation import simulate_psf


@pytest.fixture(scope="module")
def calibrated():
    scene = misaligned_fourier_scene()
    calibration = calibrate(scene.radiometry, scene.nominal, dark=scene.dark)
    return calibration, simulate_psf(fitted_design(None, calibration))


def test_a_displaced_bead_psf_comes_back_onto_the_axis(calibrated):
    calibration, stack = calibrated
    offset = (3.37, -5.81)  # where the bead happened to sit, px
    displaced = dataclasses.replace(
        stack, data=fourier_shift(stack.data.double(), offset).clamp_min(0).float()
    )
    before = float(ncc(stack.data.double(), displaced.data.double()))
    registered = register_bead_psf(displaced, calibration)
    after = float(ncc(stack.data.double(), registered.data.double()))
    assert before < 0.2  # the floor: a displaced in-focus PSF barely overlaps
    assert after > 0.99, after
    shift = registered.metadata["calibration_shift_px"]
    assert shift == pytest.approx([-offset[0], -offset[1]], abs=0.1)


def test_refusals_name_the_problem(calibrated):
    calibration, stack = calibrated
    conventional = dataclasses.replace(calibration, kind="conventional", sub_images=None, sub_image_flat=None,
                                       grid=object())  # fmt: skip
    with pytest.raises(ValueError, match=r"conventional LFM\. Fix: simulate the PSF"):
        register_bead_psf(stack, conventional)
    small = dataclasses.replace(stack, data=stack.data[:, :200, :200])
    with pytest.raises(ValueError, match=r"\(200, 200\) pixels .*\(288, 288\)\. Fix: record the bead z-scan"):
        register_bead_psf(small, calibration)
    dark = dataclasses.replace(stack, data=torch.zeros_like(stack.data))
    with pytest.raises(ValueError, match=r"no in-focus spot.*Fix"):
        register_bead_psf(dark, calibration)
