"""The reconstruct widget's input checks (Qt-free): each refusal names the layers, the values and a fix."""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.io import LightFieldImage
from lfm_studio.engine.psf_stack import ConventionalPatterns, PSFStack
from lfm_studio.engine.units import nm, um
from lfm_studio.napari_plugin.reconstruction import Settings, prepare


def _stack(*shape: int) -> PSFStack:
    """Per-depth PSFs of ``shape`` or, for a 5-D shape ``(S, S, 3, H, H)``, conventional lenslet
    patterns (3 pixels per lenslet, reach 0: ``H`` = 9)."""
    layout = None
    if len(shape) == 5:
        layout = ConventionalPatterns(
            pixels_per_lenslet=3, voxels_per_lenslet=shape[0], reach=(0, 0, 0), lenslets=(2, 2)
        )
    return PSFStack(torch.ones(*shape), (-1 * um, 0.0, 1 * um), 6.5 * um, 10.0, 525 * nm, patterns=layout)


def _prepare(stack, image, **settings):
    return prepare(stack, image, Settings(**settings), image_name="frame", psf_name="psf")


def test_matching_inputs_are_accepted():
    request = _prepare(_stack(3, 16, 16), LightFieldImage(torch.ones(16, 16), 6.5 * um), method="wiener")
    assert request.settings.method == "wiener" and request.image_name == "frame"


def test_tikhonov_takes_a_conventional_pattern_stack_and_wiener_does_not():
    conventional, image = _stack(3, 3, 3, 9, 9), LightFieldImage(torch.ones(6, 6), 6.5 * um)
    assert _prepare(conventional, image, method="tikhonov").settings.method == "tikhonov"
    with pytest.raises(ValueError, match="needs a laterally shift-invariant"):
        _prepare(conventional, image, method="wiener")


@pytest.mark.parametrize(
    ("stack", "image", "settings", "expected"),
    [
        ((3, 16, 16), LightFieldImage(torch.ones(2, 16, 16), 6.5 * um), {}, "one camera frame (Y, X)"),
        ((3, 16, 16), LightFieldImage(torch.ones(16, 16), 6.4 * um), {}, "6.4 um pixels"),
        ((3, 16, 16), LightFieldImage(torch.ones(16, 20), 6.5 * um), {}, "(16, 20) pixels"),
        (
            (3, 3, 3, 9, 9),
            LightFieldImage(torch.ones(16, 16), 6.5 * um),
            {"method": "wiener"},
            "Fourier LFM",
        ),
    ],
)
def test_mismatches_are_refused_with_the_reason(stack, image, settings, expected):
    with pytest.raises(ValueError, match="Fix:") as caught:
        _prepare(_stack(*stack), image, **settings)
    assert expected in str(caught.value)
    assert "'frame'" in str(caught.value) or "'psf'" in str(caught.value)


@pytest.mark.parametrize(
    ("settings", "expected"),
    [
        ({"method": "lucy"}, "method must be one of"),
        ({"options": {"iterations": 0}}, "iterations must be an integer >= 1"),
        ({"options": {"background": -1.0}}, "background must be a finite number >= 0"),
        ({"options": {"background": float("nan")}}, "background must be a finite number >= 0"),
        ({"method": "wiener", "options": {"snr": 0.0}}, "snr must be a finite number > 0"),
        ({"method": "wiener", "options": {"iterations": 3}}, "method 'wiener' takes no option 'iterations'"),
    ],
)
def test_invalid_settings_name_the_parameter(settings, expected):
    with pytest.raises(ValueError, match=expected):
        Settings(**settings)


def _delta_stack() -> PSFStack:
    """Three depths, each a point imaged to a different pixel (every depth is told apart)."""
    data = torch.zeros(3, 16, 16)
    for z, (y, x) in enumerate(((8, 6), (8, 8), (8, 10))):
        data[z, y, x] = 1.0
    return PSFStack(data, (-1 * um, 0.0, 1 * um), 6.5 * um, 10.0, 525 * nm)


def _camera_frame(stack: PSFStack) -> tuple[torch.Tensor, torch.Tensor]:
    """A 40-photon point and its camera frame in ADU."""
    from lfm_studio.engine.simulation import imaging_setup

    setup = imaging_setup(stack)
    truth = torch.zeros(setup.volume_shape)
    truth[1, 1, 2] = 40.0  # photons
    photons = setup.projector.forward(truth).clamp_min(0)
    return truth, 100.0 + 2.0 * 0.8 * photons  # baseline 100 ADU, gain 2 ADU/e-, QE 0.8


def test_run_converts_counts_with_the_image_camera_metadata():
    from lfm_studio.napari_plugin.reconstruction import run

    stack = _delta_stack()
    _, counts = _camera_frame(stack)
    meta = {
        "units": "ADU",
        "camera": {"baseline_adu": 100.0, "gain_adu_per_e": 2.0, "quantum_efficiency": 0.8},
    }
    request = _prepare(stack, LightFieldImage(counts, 6.5 * um, meta), options={"iterations": 50})
    volume = run(request, lambda *a: None, None)
    assert volume.metadata["units"] == "photons per voxel" and volume.metadata["notes"] == []
    assert volume.metadata["camera"]["source"] == "image metadata"
    # photons back (40 were put in), not ADU above the baseline (64): (ADU - 100) / 2 / 0.8;
    # RL models the camera's noise floor as background, so 50 iterations land within 3 %
    assert float(volume.data.sum()) == pytest.approx(40.0, rel=0.03)


def test_run_estimates_the_baseline_of_a_foreign_image_and_says_so():
    from lfm_studio.napari_plugin.reconstruction import run

    stack = _delta_stack()
    _, counts = _camera_frame(stack)
    volume = run(
        _prepare(stack, LightFieldImage(counts, 6.5 * um), options={"iterations": 5}), lambda *a: None, None
    )
    notes = volume.metadata["notes"]
    assert volume.metadata["camera"]["source"] == "estimated" and "estimated the baseline as 100" in notes[0]


def test_run_refuses_an_all_zero_result(monkeypatch):
    from lfm_studio.engine import reconstruct
    from lfm_studio.engine.reconstruct import ReconstructionRejectedError
    from lfm_studio.napari_plugin.reconstruction import run

    stack = _delta_stack()
    _, counts = _camera_frame(stack)
    monkeypatch.setattr(reconstruct, "reconstruct_frame", lambda projector, frame, **kw: torch.zeros(3, 4, 4))
    with pytest.raises(ReconstructionRejectedError, match="'frame' with 'psf' is all zero"):
        run(
            _prepare(stack, LightFieldImage(counts, 6.5 * um), baseline=100.0, gain=1.0),
            lambda *a: None,
            None,
        )


def test_a_raw_frame_with_a_calibration_is_refused_for_wiener_on_a_conventional_stack():
    # The calibration path used to return before this check and rectify the frame first.
    image = LightFieldImage(torch.ones(16, 16), 6.5 * um)
    with pytest.raises(ValueError, match="Fourier LFM"):
        prepare(
            _stack(3, 3, 3, 9, 9), image, Settings(method="wiener"), image_name="frame", psf_name="psf",
            calibration=object(), calibration_name="calib.json",
        )  # fmt: skip


def test_a_psf_sampled_finer_than_the_camera_is_matched_to_camera_frames():
    # volume_oversampling 3: PSFs on a virtual sensor of 2.1667 um pixels, 3 x 3 per 6.5 um camera pixel
    # (16 camera pixels: 3 * 16 + 2 virtual ones on an even axis). The frame is the camera's.
    fine = PSFStack(
        torch.ones(3, 50, 50), (-1 * um, 0.0, 1 * um), 6.5 * um / 3, 10.0, 525 * nm, volume_oversampling=3
    )
    assert fine.camera_shape == (16, 16) and fine.camera_pixel_size == pytest.approx(6.5 * um)
    assert _prepare(fine, LightFieldImage(torch.ones(16, 16), 6.5 * um)).psf_name == "psf"
    with pytest.raises(ValueError, match=r"\(50, 50\) pixels but the PSF layer 'psf' covers a \(16, 16\)"):
        _prepare(fine, LightFieldImage(torch.ones(50, 50), 6.5 * um))
    with pytest.raises(ValueError, match=r"2\.16667 um pixels"):
        _prepare(fine, LightFieldImage(torch.ones(16, 16), 6.5 * um / 3))
