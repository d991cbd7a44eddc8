"""Flat-field envelope: closed-form recovery and the effect on a calibrated synthetic frame."""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.calibration import LensletLattice, calibrate, correct_frame
from lfm_studio.engine.calibration.flat_field import envelope_at, envelope_map, fit_envelope, flat_field
from lfm_studio.engine.calibration.synthetic import (
    conventional_design_for,
    radial_vignetting,
    synthetic_frames,
)


def test_envelope_of_a_quadratic_vignetting_is_recovered_exactly():
    shape = (200, 260)
    points = torch.rand(300, 2, generator=torch.Generator().manual_seed(1)) * torch.tensor([199.0, 259.0])
    truth = radial_vignetting(shape, 0.4)
    light = 5000.0 * truth[points[:, 0].round().long(), points[:, 1].round().long()]
    points = points.round()
    coefficients = fit_envelope(points, light, shape)
    envelope = envelope_map(coefficients, shape)
    expected = truth / truth[points[:, 0].long(), points[:, 1].long()].median()
    assert torch.allclose(envelope, expected, atol=1e-9)
    assert torch.allclose(
        envelope_at(coefficients, points, shape), envelope[points[:, 0].long(), points[:, 1].long()]
    )
    frame = 7.0 * truth
    assert torch.allclose(
        flat_field(frame, coefficients),
        torch.full(
            shape, float(7.0 * truth[points[:, 0].long(), points[:, 1].long()].median()), dtype=torch.float64
        ),
        rtol=1e-9,
    )


def test_flat_fielded_lenslets_carry_equal_light():
    shape = (384, 400)
    truth = LensletLattice.from_geometry((15.38, 15.38), math.radians(0.8), (190.0, 201.0))
    frames = synthetic_frames(shape, truth, disk_diameter=13.8, vignetting=0.4, seed=2)
    calibration = calibrate(frames.radiometry, conventional_design_for(15.38, shape), dark=frames.dark)
    grid = calibration.grid
    centres = grid.measured[grid.used].round().long().tolist()

    def light(image: torch.Tensor) -> torch.Tensor:  # 15 x 15 box sums around each lenslet
        return torch.tensor([float(image[r - 7 : r + 8, c - 7 : c + 8].sum()) for r, c in centres])

    before = light(frames.radiometry - frames.dark.median())
    after = light(correct_frame(frames.radiometry, calibration))
    spread_before = float(before.std() / before.mean())
    spread_after = float(after.std() / after.mean())
    assert spread_before > 0.05  # 40 % vignetting: the lenslets differ a lot
    assert spread_after < 0.01  # flat fielded: the same light within 1 %
