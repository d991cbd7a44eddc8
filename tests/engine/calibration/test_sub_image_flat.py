"""Fourier LFM flat field per sub-image, on synthetic frames with a known gain per sub-image.

Truth: each sub-image ``l`` of a uniform slide carries ``gain_l`` (0.55 to 1.3, a different
vignetting per lenslet) on top of a 30 % frame-wide radial vignetting. The calibration's
per-sub-image gains must match the truth's relative light per sub-image, and a second,
independent exposure of the slide must come out with the same light in every sub-image
(the uncorrected frame, the trivial answer, differs by tens of per cent).
"""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.calibration import calibrate, correct_frame, load_calibration, save_calibration
from lfm_studio.engine.calibration.nominal import nominal_sub_images
from lfm_studio.engine.calibration.sub_image_flat import (
    INTERIOR,
    SubImageFlat,
    fit_sub_image_flat,
    sub_image_flat_map,
)
from lfm_studio.engine.calibration.synthetic import fourier_frames, radial_vignetting, sub_image_pattern
from lfm_studio.engine.design import load_preset

SHAPE = (288, 288)
GAINS = torch.tensor([1.0, 0.62, 1.3, 0.85, 1.1, 0.55, 0.95, 1.2, 0.7], dtype=torch.float64)


def _design():
    design = load_preset("flfm_guo2019")
    return design.updated(camera={**design.camera.model_dump(), "pixel_count": SHAPE})


def _interior_means(image: torch.Tensor, centres: torch.Tensor, radius: float) -> torch.Tensor:
    yy, xx = torch.meshgrid(
        torch.arange(SHAPE[0], dtype=torch.float64),
        torch.arange(SHAPE[1], dtype=torch.float64),
        indexing="ij",
    )
    means = []
    for cy, cx in centres.tolist():
        inside = (yy - cy) ** 2 + (xx - cx) ** 2 <= (0.8 * radius) ** 2
        means.append(float(image[inside].mean()))
    return torch.tensor(means, dtype=torch.float64)


@pytest.fixture(scope="module")
def calibrated():
    design = _design()
    radiometry, dark, truth = fourier_frames(
        design, SHAPE, rotation_deg=0.8, shift=(1.5, -1.0), gains=GAINS, seed=6
    )
    return design, calibrate(radiometry, design, dark=dark), truth


def test_the_gain_of_each_sub_image_is_recovered(calibrated):
    design, calibration, truth = calibrated
    flat = calibration.sub_image_flat
    assert flat is not None and flat.coefficients.shape[0] == 9
    radius = flat.radius
    gain_map = sub_image_flat_map(flat, calibration.sub_images.measured, SHAPE)
    measured = _interior_means(gain_map, truth, radius)
    # Truth: the noise-free light of each sub-image (its gain times the radial vignetting over it).
    diameter = 0.97 * nominal_sub_images(design, SHAPE).diameter
    light = sub_image_pattern(SHAPE, truth, diameter, GAINS) * radial_vignetting(SHAPE, 0.3)
    expected = _interior_means(light, truth, radius)
    ratio = measured / expected
    assert float(ratio.std() / ratio.mean()) < 0.005, ratio  # relative gains within 0.5 %
    # Outside every sub-image the frame is left alone.
    assert float(gain_map[0, 0]) == 1.0 and float(gain_map[-1, -1]) == 1.0


def test_a_new_exposure_has_the_same_light_in_every_sub_image(calibrated, tmp_path):
    design, calibration, truth = calibrated
    raw, _, _ = fourier_frames(design, SHAPE, rotation_deg=0.8, shift=(1.5, -1.0), gains=GAINS, seed=11)
    radius = calibration.sub_image_flat.radius
    before = _interior_means(raw - 100.0, truth, radius)
    after = _interior_means(correct_frame(raw, calibration), truth, radius)
    assert float(before.std() / before.mean()) > 0.25  # the trivial (uncorrected) answer
    assert float(after.std() / after.mean()) < 0.01
    # Within a sub-image the radial vignetting is gone too: the interior is flat to the shot noise.
    corrected = correct_frame(raw, calibration)
    cy, cx = (round(v) for v in truth[2].tolist())
    core = corrected[cy - 8 : cy + 9, cx - 8 : cx + 9]
    assert float(core.std() / core.mean()) < 0.05  # ~1/sqrt(1500 x 1.3) = 2.3 % shot noise
    # The gains survive the calibration file.
    save_calibration(calibration, tmp_path / "c.json")
    loaded = load_calibration(tmp_path / "c.json")
    assert torch.allclose(loaded.sub_image_flat.coefficients, calibration.sub_image_flat.coefficients)
    assert torch.allclose(correct_frame(raw, loaded), corrected)


def test_a_blocked_sub_image_keeps_gain_one():
    centres = torch.tensor([[40.0, 40.0], [40.0, 120.0], [120.0, 40.0]], dtype=torch.float64)
    image = 500.0 * sub_image_pattern((160, 160), centres, 50.0, torch.tensor([1.0, 0.5, 2.0]))
    flags = torch.tensor([0, 2, 0])  # the second one is DIM
    flat = fit_sub_image_flat(image, centres, flags, 50.0)
    assert torch.allclose(flat.coefficients[1], torch.tensor([1.0, 0, 0, 0, 0, 0], dtype=torch.float64))
    gain = sub_image_flat_map(flat, centres, (160, 160))
    # Median of the two fitted sub-images (1.0 and 2.0 times 500) is 1.5 x 500.
    assert float(gain[40, 40]) == pytest.approx(1.0 / 1.5, rel=1e-6)
    assert float(gain[120, 40]) == pytest.approx(2.0 / 1.5, rel=1e-6)
    assert INTERIOR < 1.0


def test_bad_flat_field_input_is_named():
    with pytest.raises(ValueError, match=r"coefficients must be \(L, 6\)"):
        SubImageFlat(coefficients=torch.ones(3, 2, dtype=torch.float64), radius=5.0)
    centres = torch.tensor([[40.0, 40.0]], dtype=torch.float64)
    with pytest.raises(ValueError, match=r"no light above the dark level.*Fix"):
        fit_sub_image_flat(torch.zeros(80, 80, dtype=torch.float64), centres, torch.tensor([0]), 40.0)
