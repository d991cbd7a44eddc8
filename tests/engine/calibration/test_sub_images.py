"""Fourier LFM: sub-image centres measured on a synthetic radiometry frame with known truth."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.calibration import calibrate, fitted_design, grid_overlay
from lfm_studio.engine.calibration.grid_fit import RESIDUAL
from lfm_studio.engine.calibration.nominal import nominal_sub_images
from lfm_studio.engine.calibration.sub_images import fit_sub_images
from lfm_studio.engine.calibration.synthetic import (
    expose,
    fourier_frames,
    radial_vignetting,
    sub_image_pattern,
)
from lfm_studio.engine.design import load_preset

SHAPE = (288, 288)


def _small_flfm():
    design = load_preset("flfm_guo2019")
    camera = design.camera.model_copy(update={"pixel_count": SHAPE})
    return design.updated(camera=camera.model_dump())


def _frames(truth: torch.Tensor, diameter: float, seed: int):
    clean = 1500.0 * sub_image_pattern(SHAPE, truth, diameter) * radial_vignetting(SHAPE, 0.3)
    return expose(
        clean,
        baseline_adu=100.0,
        read_noise_e=1.5,
        gain_adu_per_e=1.0,
        hot_fraction=1e-3,
        hot_adu=3000.0,
        seed=seed,
    )


def test_sub_image_centres_and_registration():
    design = _small_flfm()
    nominal = nominal_sub_images(design, SHAPE)
    radiometry, dark, truth = fourier_frames(
        design, SHAPE, rotation_deg=1.2, scale=1.005, shift=(1.0, -2.0), seed=4
    )
    calibration = calibrate(radiometry, design, dark=dark)
    fit = calibration.sub_images
    rms = float((fit.measured - truth).norm(dim=1).pow(2).mean().sqrt())
    assert rms <= 0.1
    nominal_rms = float((nominal.centres - truth).norm(dim=1).pow(2).mean().sqrt())
    assert nominal_rms > 2.0  # the design's own centres are far off: the bound tests the measurement
    assert fit.scale == pytest.approx(1.005, abs=0.003)
    assert math.degrees(fit.rotation) == pytest.approx(1.2, abs=0.2)
    assert int((fit.flags != 0).sum()) == 0
    # The fitted design puts each lenslet where its sub-image was measured.
    fitted = fitted_design(design, calibration)
    pixel = design.camera.pixel_pitch_um
    centres = torch.tensor(
        [
            [y / pixel + SHAPE[0] // 2, x / pixel + SHAPE[1] // 2]
            for x, y in (lens.center_um for lens in fitted.mla.lenslets)
        ],
        dtype=torch.float64,
    )
    assert torch.allclose(centres, fit.measured, atol=1e-6)


def test_a_displaced_sub_image_is_flagged():
    design = _small_flfm()
    nominal = nominal_sub_images(design, SHAPE)
    jitter = torch.randn(
        nominal.centres.shape, generator=torch.Generator().manual_seed(5), dtype=torch.float64
    )
    truth = nominal.centres + 0.3 * jitter
    truth[4] += torch.tensor([4.0, -3.0], dtype=torch.float64)  # one lenslet glued 5 px off
    radiometry, _, _ = _frames(truth, 0.9 * nominal.diameter, seed=5)
    fit = fit_sub_images(radiometry - 100.0, nominal)
    assert int(fit.flags[4]) & RESIDUAL
    assert int((fit.flags != 0).sum()) == 1
    assert float((fit.measured[4] - truth[4]).norm()) <= 0.2  # still measured where it is


def test_overlay_draws_registered_and_measured_centres():
    design = _small_flfm()
    radiometry, dark, truth = fourier_frames(design, SHAPE, rotation_deg=-0.7, scale=0.998, seed=8)
    calibration = calibrate(radiometry, design, dark=dark)
    overlay = grid_overlay(calibration)
    fit = calibration.sub_images
    assert torch.allclose(overlay.measured, fit.measured)
    assert float((overlay.measured - truth).norm(dim=1).max()) < 0.1
    # The registered design centres lie within the residuals of the measured ones.
    distances = (overlay.fitted - overlay.measured).norm(dim=1)
    assert torch.allclose(distances, fit.residual, atol=1e-9)
    assert float(distances.max()) < 1.5  # jitter 0.3 px rms per axis
    assert overlay.flags == ((),) * 9


def test_a_frame_too_small_for_the_design_is_refused_naming_both_shapes():
    """A 188 x 192 frame (a conventional LFM's) against the XLFM preset: no sub-image lies whole on it,
    which used to crash in torch.quantile on an empty crop."""
    nominal = nominal_sub_images(load_preset("xlfm_cong2017"), (188, 192))
    with pytest.raises(
        ValueError, match=r"frame is 188 x 192 px, but the design's 27 sub-images .* span about"
    ) as info:
        fit_sub_images(torch.full((188, 192), 500.0, dtype=torch.float64), nominal)
    assert "only 0 of them would lie whole on it" in str(info.value) and "Fix: " in str(info.value)


def test_sub_images_off_the_frame_are_flagged_not_a_crash():
    """An 800 px crop of the XLFM frame: 3 sub-images lie whole, 13 are off it entirely (empty windows)."""
    shape = (800, 800)
    nominal = nominal_sub_images(load_preset("xlfm_cong2017"), shape)
    truth = nominal.centres + torch.tensor([1.0, -0.5], dtype=torch.float64)
    frame = 1000.0 * sub_image_pattern(shape, truth, nominal.diameter)
    fit = fit_sub_images(frame, nominal)
    off = ((nominal.centres < -200) | (nominal.centres > 1000)).any(dim=1)
    assert int(off.sum()) >= 10 and bool((fit.flags[off] != 0).all())
    whole = fit.flags == 0
    assert int(whole.sum()) >= 2
    assert float((fit.measured[whole] - truth[whole]).norm(dim=1).max()) < 0.5
