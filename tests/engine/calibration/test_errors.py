"""Bad input to a calibration gets an error that names the input, its value and a fix."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.calibration import LensletLattice, NoGridError, calibrate, correct_frame
from lfm_studio.engine.calibration.synthetic import conventional_design_for, synthetic_frames

SHAPE = (256, 272)


@pytest.fixture(scope="module")
def frames():
    truth = LensletLattice.from_geometry((15.38, 15.38), math.radians(0.5), (130.0, 133.0))
    return synthetic_frames(SHAPE, truth, disk_diameter=13.8, seed=1)


@pytest.fixture(scope="module")
def design():
    return conventional_design_for(15.38, SHAPE)


def test_frame_without_a_grid(design):
    noise = 100.0 + 30.0 * torch.rand(SHAPE, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    with pytest.raises(NoGridError, match=r"no lenslet grid.*nominal pitch 15.38 px.*Fix: record"):
        calibrate(noise, design)


def test_grid_far_from_the_nominal_pitch(frames):
    wrong = conventional_design_for(15.38 * 1.3, SHAPE)
    with pytest.raises(
        ValueError, match=r"far from the design: measured pitch 15.3\d* x 15.3\d* px.*predicts 19.99 px.*Fix"
    ):
        calibrate(frames.radiometry, wrong, dark=frames.dark)


def test_saturated_frame(frames, design):
    # The design's camera saturates at baseline 100 + full well 30000 e- x 1 ADU/e-.
    saturated = (frames.radiometry * 40.0).clamp(max=30100.0)
    with pytest.raises(
        ValueError, match=r"radiometry frame is saturated: \d+ % of its pixels.*30100 ADU.*shorter exposure"
    ):
        calibrate(saturated, design)


def test_frame_clipped_below_the_design_saturation(frames, design):
    clipped = frames.radiometry.clamp(max=1500.0)  # e.g. a 12-bit camera behind a 16-bit design
    with pytest.raises(ValueError, match=r"radiometry frame is saturated: \d+ % of its pixels.*1500 ADU"):
        calibrate(clipped, design)


def test_dark_brighter_than_radiometry(frames, design):
    with pytest.raises(ValueError, match=r"dark frame \(mean .* ADU\) is not darker.*swapped"):
        calibrate(frames.dark, design, dark=frames.radiometry)


def test_mismatched_shapes(frames, design):
    with pytest.raises(ValueError, match=r"dark frame shape \(256, 270\) differs.*\(256, 272\).*Fix"):
        calibrate(frames.radiometry, design, dark=frames.dark[:, :270])
    calibration = calibrate(frames.radiometry, design, dark=frames.dark)
    with pytest.raises(ValueError, match=r"raw frame shape \(250, 272\) differs.*\(256, 272\).*Fix"):
        correct_frame(frames.radiometry[:250], calibration)


def test_not_a_single_frame_or_not_finite(frames, design):
    with pytest.raises(ValueError, match=r"radiometry must be one 2D camera frame.*\(2, 256, 272\).*Fix"):
        calibrate(torch.stack((frames.radiometry, frames.radiometry)), design)
    bad = frames.radiometry.clone()
    bad[3, 4] = float("nan")
    with pytest.raises(ValueError, match=r"radiometry contains 1 NaN/Inf"):
        calibrate(bad, design)
