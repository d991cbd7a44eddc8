"""What reconstruction needs beside a calibration: the design whose projector images the rectified
frame (:func:`rectified_design`), and the camera conversion of dark-subtracted frames (baseline 0)."""

from __future__ import annotations

import dataclasses
import math

import pytest

from lfm_studio.engine.calibration import LensletLattice, calibrate, rectified_design, rectify_frame
from lfm_studio.engine.calibration.raw_camera import dark_subtracted_camera
from lfm_studio.engine.calibration.synthetic import conventional_design_for, synthetic_frames
from lfm_studio.engine.io import counts_to_photons
from lfm_studio.engine.systems.from_design import conventional_system_of

SHAPE = (256, 288)


@pytest.fixture(scope="module")
def calibrated():
    truth = LensletLattice.from_geometry((15.38, 15.38), math.radians(1.4), (131.7, 140.2))
    frames = synthetic_frames(SHAPE, truth, disk_diameter=13.8, seed=3)
    design = conventional_design_for(15.38, SHAPE)
    return design, frames, calibrate(frames.radiometry, design, dark=frames.dark)


@pytest.mark.parametrize("lenslets", [None, (5, 7)])
def test_the_rectified_design_images_the_rectified_frame(calibrated, lenslets):
    design, frames, calibration = calibrated
    rectified = rectify_frame(frames.radiometry, calibration, lenslets=lenslets)
    psf_design = rectified_design(design, calibration, lenslets=lenslets)
    system = conventional_system_of(psf_design)  # the projector's own choice of lenslets and pixels
    n = system.pixels_per_lenslet
    assert n == calibration.pixels_per_lenslet == 15  # 15.38 px rounded to the nearest odd number
    assert (system.lenslets[0] * n, system.lenslets[1] * n) == tuple(rectified.shape)
    assert psf_design.mla.offset_um == (0.0, 0.0)
    assert psf_design.mla.pitch_um == design.mla.pitch_um  # the nominal optics; rectification did the rest
    assert any(note.startswith("rectified:") for note in psf_design.assumed)


def test_a_fourier_design_has_no_rectified_design(calibrated):
    from lfm_studio.engine.calibration.synthetic import fourier_frames
    from lfm_studio.engine.design import load_preset

    design = load_preset("flfm_guo2019")
    shape = (288, 288)
    design = design.updated(camera={**design.camera.model_dump(), "pixel_count": shape})
    radiometry, dark, _ = fourier_frames(design, shape, rotation_deg=0.8, shift=(1.5, -1.0), seed=6)
    with pytest.raises(ValueError, match=r"needs a conventional calibration.*Fix: use fitted_design"):
        rectified_design(design, calibrate(radiometry, design, dark=dark))


def test_dark_subtracted_frames_convert_with_baseline_zero(calibrated):
    design, frames, calibration = calibrated
    camera = dark_subtracted_camera(calibration)
    assert camera.baseline_adu == 0.0
    assert camera.gain_adu_per_e == design.camera.gain_adu_per_e  # no metadata: the design camera
    metadata = {"camera": {"baseline_adu": 100.0, "gain_adu_per_e": 2.0, "quantum_efficiency": 0.5}}
    recorded = dark_subtracted_camera(calibration, metadata)
    assert (recorded.baseline_adu, recorded.gain_adu_per_e, recorded.quantum_efficiency) == (0.0, 2.0, 0.5)
    assert dark_subtracted_camera(calibration, metadata, gain=4.0, read_noise=0.0).gain_adu_per_e == 4.0
    assert dark_subtracted_camera(calibration, metadata, quantum_efficiency=0.7).quantum_efficiency == 0.7
    assert dark_subtracted_camera(calibration, quantum_efficiency=0.7).quantum_efficiency == 0.7
    # A dark frame corrected by its own calibration holds no light: its photons are the noise floor
    # alone (mean within 1 e-), whereas subtracting the dark level again clips it all to about 0.
    dark = rectify_frame(frames.dark, calibration)
    photons, floor = counts_to_photons(dark, camera, name="dark")
    assert floor > 3.0 and float(photons.mean()) == pytest.approx(floor, abs=1.0)
    twice = dataclasses.replace(camera, baseline_adu=calibration.dark_level)
    assert float(counts_to_photons(dark, twice, name="dark")[0].mean()) < 0.1 * floor


def test_a_series_prepares_its_corrections_once(calibrated, monkeypatch):
    """Defect mask, dark frame and flat-field map are built once per series, not once per frame."""
    import torch

    from lfm_studio.engine.calibration import corrections, pipeline

    _, frames, calibration = calibrated
    single = rectify_frame(frames.radiometry, calibration)
    calls = []
    original = corrections.frame_corrections

    def counted(calibration):
        calls.append(1)
        return original(calibration)

    monkeypatch.setattr(pipeline, "frame_corrections", counted)
    series = torch.stack((frames.radiometry, 0.5 * frames.radiometry, frames.radiometry))
    out = rectify_frame(series, calibration)
    assert len(calls) == 1
    assert out.shape == (3, *single.shape)
    assert torch.allclose(out[0], single) and torch.allclose(out[2], single)
    # Frame 1 is half the light above the same dark frame: the dark is subtracted from each frame.
    half = rectify_frame(0.5 * frames.radiometry, calibration)
    assert torch.allclose(out[1], half)
    assert not torch.allclose(out[1], 0.5 * single, rtol=1e-3)  # 0.5 x raw still carries the full dark
