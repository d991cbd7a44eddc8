"""The reconstruct widget's input checks (Qt-free): each refusal names the layers, the values and a fix."""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.io import LightFieldImage
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.units import nm, um
from lfm_studio.napari_plugin.reconstruction import Settings, prepare


def _stack(*shape: int) -> PSFStack:
    return PSFStack(torch.ones(*shape), (-1 * um, 0.0, 1 * um), 6.5 * um, 10.0, 525 * nm)


def _prepare(stack, image, **settings):
    return prepare(stack, image, Settings(**settings), image_name="frame", psf_name="psf")


def test_matching_inputs_are_accepted():
    request = _prepare(_stack(3, 16, 16), LightFieldImage(torch.ones(16, 16), 6.5 * um), method="wiener")
    assert request.settings.method == "wiener" and request.image_name == "frame"


@pytest.mark.parametrize(
    ("stack", "image", "settings", "expected"),
    [
        ((3, 16, 16), LightFieldImage(torch.ones(2, 16, 16), 6.5 * um), {}, "one camera frame (Y, X)"),
        ((3, 16, 16), LightFieldImage(torch.ones(16, 16), 6.4 * um), {}, "6.4 um pixels"),
        ((3, 16, 16), LightFieldImage(torch.ones(16, 20), 6.5 * um), {}, "(16, 20) pixels"),
        (
            (2, 2, 3, 8, 8),
            LightFieldImage(torch.ones(16, 16), 6.5 * um),
            {"method": "tikhonov"},
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
        ({"iterations": 0}, "iterations must be an integer >= 1"),
        ({"background": -1.0}, "background must be a finite number >= 0"),
        ({"background": float("nan")}, "background must be a finite number >= 0"),
        ({"method": "wiener", "snr": 0.0}, "SNR must be a finite number > 0"),
    ],
)
def test_invalid_settings_name_the_parameter(settings, expected):
    with pytest.raises(ValueError, match=expected):
        Settings(**settings)
