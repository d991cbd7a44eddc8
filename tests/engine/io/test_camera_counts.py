"""Camera counts <-> photons: the closed-form conversion, the baseline estimate, what wins over what."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lfm_studio.engine.io import CameraCalibration, camera_metadata, counts_to_photons, resolve_calibration
from lfm_studio.engine.io.camera_counts import adu_array, calibration_from_metadata, estimate_baseline
from lfm_studio.engine.optics.camera import Camera, simulate_sensor

CAMERA = Camera(
    pixel_pitch=6.5e-6, quantum_efficiency=0.8, read_noise=1.5, gain=2.0, bit_depth=12, baseline=100.0
)


def test_counts_to_photons_inverts_the_noise_free_camera():
    photons = torch.rand(32, 32, dtype=torch.float64) * 50
    adu = simulate_sensor(photons, CAMERA, shot_noise=False, read_noise=False, quantize=False, saturate=False)
    meta = {"units": "ADU", "camera": camera_metadata(CAMERA, photons=None, seed=0)}
    calibration, notes = resolve_calibration(meta, adu)
    assert notes == [] and calibration.source == "image metadata" and calibration.read_noise_e == 1.5
    out, background = counts_to_photons(adu, calibration, name="x")
    # The noise floor max(s^2, 3 s), s^2 = 1.5^2 + 1 / (12 * 2^2), rides on every pixel as background.
    floor = max(1.5**2 + 1 / 48, 3 * (1.5**2 + 1 / 48) ** 0.5)
    assert calibration.noise_floor_e == pytest.approx(floor, rel=1e-12)
    assert background == pytest.approx(floor / 0.8, rel=1e-12)
    assert torch.allclose(out - background, photons, rtol=1e-12, atol=1e-12)


def test_below_the_noise_floor_is_clipped_at_zero():
    calibration = CameraCalibration(100.0, 2.0, 0.5)  # no read noise: the floor is the ADC rounding
    c = 3 * (1 / 48) ** 0.5  # electrons: 3 sigma of a uniform rounding error of 1/2 ADU = 1/4 e-
    out, background = counts_to_photons(torch.tensor([90.0, 100.0, 110.0]), calibration, name="x")
    assert background == pytest.approx(c / 0.5, rel=1e-12)
    assert out.tolist() == pytest.approx([0.0, c / 0.5, (5 + c) / 0.5], rel=1e-6)  # (110 - 100) / 2 = 5 e-


def test_the_noise_floor_removes_the_clipping_bias_of_read_noise():
    """A dark frame (read noise only): clipped at 0 it shows 0.4 sigma of fake light per pixel
    (sigma / sqrt(2 pi)); shifted by the floor and with the floor as background, almost none."""
    sigma = 1.5
    dark = 100.0 + sigma * torch.randn(
        1_000_000, generator=torch.Generator().manual_seed(0), dtype=torch.float64
    )
    calibration = CameraCalibration(100.0, 1.0, 1.0, read_noise_e=sigma, quantized=False)
    out, background = counts_to_photons(dark, calibration, name="dark")
    assert float(out.mean()) - background == pytest.approx(0.0, abs=0.01 * sigma)
    clipped = float((dark - 100.0).clamp_min(0).mean())
    assert clipped == pytest.approx(sigma / (2 * torch.pi) ** 0.5, rel=0.01)


def test_adu_array_is_uint16_and_saturates():
    counts = torch.tensor([-3.0, 12.4, 70000.0])
    stored = adu_array(counts, 16)
    assert stored.dtype == torch.uint16 and stored.tolist() == [0, 12, 65535]
    assert adu_array(torch.tensor([4095.0]), 12).tolist() == [4095]
    assert adu_array(torch.tensor([2.0**20]), 20).dtype == torch.float32  # > 16 bits: float32 integers


def test_foreign_image_gets_an_estimated_baseline_and_a_warning():
    generator = torch.Generator().manual_seed(0)
    frame = 100.0 + torch.randn(64, 64, generator=generator)  # dark frame: baseline 100, 1 ADU noise
    frame[10:14, 10:14] += 500.0  # a little light
    calibration, notes = resolve_calibration({}, frame)
    assert 96.0 < calibration.baseline_adu < 100.0  # 1st percentile: ~2.3 sigma below the baseline
    assert calibration.gain_adu_per_e == 1.0 and not calibration.gain_known
    assert calibration.volume_units == "ADU above the baseline per voxel"
    assert len(notes) == 2 and "--baseline" in notes[0] and f"{calibration.baseline_adu:.6g}" in notes[0]
    assert "--gain" in notes[1]


def test_options_win_over_metadata_and_silence_the_warning():
    meta = {"units": "ADU", "camera": camera_metadata(CAMERA, photons=1e6, seed=1)}
    calibration, notes = resolve_calibration(meta, torch.zeros(4, 4), baseline=90.0)
    assert notes == [] and calibration.baseline_adu == 90.0 and calibration.gain_adu_per_e == 2.0
    calibration, notes = resolve_calibration({}, torch.zeros(4, 4), baseline=50.0, gain=0.5)
    assert notes == [] and calibration.gain_known and calibration.quantum_efficiency == 1.0


def test_noise_free_images_are_already_photons():
    calibration = calibration_from_metadata({"units": "photons", "camera": None})
    assert calibration == CameraCalibration(source="noise-free image", quantized=False)
    assert calibration.noise_floor_e == 0.0  # no camera, no floor: the data pass unchanged
    out, background = counts_to_photons(torch.tensor([0.0, 2.5]), calibration, name="x")
    assert out.tolist() == [0.0, 2.5] and background == 0.0


def test_counts_to_photons_takes_numpy_counts_like_the_tensor_they_hold():
    adu = np.array([[100, 104, 180], [4095, 100, 96]], dtype=np.uint16)  # raw 12-bit counts
    calibration = CameraCalibration(baseline_adu=100.0, gain_adu_per_e=2.0, quantum_efficiency=0.8)
    photons, background = counts_to_photons(adu, calibration, name="frame")
    expected, same = counts_to_photons(torch.tensor(adu.astype(np.float32)), calibration, name="frame")
    assert photons.dtype == torch.float32 and background == same
    assert torch.equal(photons, expected)
    double, _ = counts_to_photons(adu.astype(np.float64), calibration, name="frame")
    assert double.dtype == torch.float64 and torch.allclose(double, expected.double())


def test_nan_pixels_are_refused_by_name():
    frame = torch.full((8, 8), 120.0)
    frame[2, 3] = float("nan")
    frame[4, 4] = float("inf")
    calibration, _ = resolve_calibration({}, frame)
    assert calibration.baseline_adu == pytest.approx(120.0)  # the estimate ignores non-finite pixels
    with pytest.raises(ValueError, match=r"lf\.tif has 2 NaN/Inf pixel\(s\) of 64.*Fix:"):
        counts_to_photons(frame, calibration, name="lf.tif")
    assert estimate_baseline(torch.full((3, 3), float("nan"))) == 0.0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"baseline_adu": -1.0}, "baseline must be a finite number >= 0 ADU"),
        ({"gain_adu_per_e": 0.0}, "gain must be a finite number > 0"),
        ({"quantum_efficiency": 1.5}, r"quantum_efficiency must be in \(0, 1\]"),
    ],
)
def test_invalid_calibration_is_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        CameraCalibration(**kwargs)


def test_incomplete_camera_metadata_asks_for_the_options():
    with pytest.raises(ValueError, match="Fix: pass --baseline and --gain"):
        calibration_from_metadata({"camera": {"baseline_adu": 100.0}})


def test_a_designs_camera_is_undone_as_the_metadata_of_its_simulated_image_says():
    """design_camera (the studio's and the task score's conversion) reads the design's camera as
    the image metadata of a frame simulated with it records it: the same four numbers."""
    from lfm_studio.engine.design import load_preset
    from lfm_studio.engine.io.camera_counts import design_camera
    from lfm_studio.engine.simulation import camera_of

    design = load_preset("flfm_guo2019")
    spec = design.camera.model_copy(
        update={"baseline_adu": 100.0, "gain_adu_per_e": 2.0, "read_noise_e": 1.5}
    )
    ours = design_camera(spec, "the design's camera")
    recorded = calibration_from_metadata(
        {"camera": camera_metadata(camera_of(design.updated(camera=spec)), photons=None, seed=0)}
    )
    assert ours.source == "the design's camera" and recorded is not None
    fields = (
        "baseline_adu",
        "gain_adu_per_e",
        "quantum_efficiency",
        "read_noise_e",
        "gain_known",
        "quantized",
    )
    assert [getattr(ours, f) for f in fields] == [getattr(recorded, f) for f in fields]
    assert (ours.baseline_adu, ours.gain_adu_per_e, ours.read_noise_e) == (100.0, 2.0, 1.5)


def test_a_given_quantum_efficiency_wins_over_the_metadata_and_the_default():
    meta = {"units": "ADU", "camera": camera_metadata(CAMERA, photons=1e6, seed=1)}
    calibration, notes = resolve_calibration(
        {}, torch.zeros(4, 4), baseline=50.0, gain=0.5, quantum_efficiency=0.8
    )
    assert notes == [] and calibration.quantum_efficiency == 0.8
    calibration, _ = resolve_calibration(meta, torch.zeros(4, 4), quantum_efficiency=0.6)
    assert calibration.quantum_efficiency == 0.6 and calibration.source == "image metadata"
    calibration, _ = resolve_calibration(meta, torch.zeros(4, 4), baseline=90.0, quantum_efficiency=0.6)
    assert calibration.quantum_efficiency == 0.6 and calibration.baseline_adu == 90.0
    with pytest.raises(ValueError, match=r"quantum_efficiency must be in \(0, 1\]; got 1.5.*Fix"):
        resolve_calibration({}, torch.zeros(4, 4), baseline=50.0, gain=0.5, quantum_efficiency=1.5)
