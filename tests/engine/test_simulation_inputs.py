"""Bad input to the simulation pipeline (simulate_psf, light_field_image, make_phantom) is refused
at once, naming the parameter, the value and the fix; questionable input warns."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from lfm_studio.engine.design import DepthSpec, DesignWarning, load_preset
from lfm_studio.engine.simulation import simulate_psf, source_depths
from lfm_studio.engine.units import um


@pytest.fixture(scope="module")
def design():
    return load_preset("flfm_guo2019")  # depths -40 .. 40 um


def test_depths_in_micrometres_are_refused_at_once_with_the_metre_values(design):
    # The old call never returned: a 10 m defocus planned a window of 1e8 samples per side.
    with pytest.raises(
        ValueError,
        match=r"depths must be in metres, within 1 mm of focus; got \(-10, 0, 10\) m.*this design's range "
        r"is -40 \.\. 40 um\)\. Fix: did you pass um\? Use depths=\(-10 \* um, 0 \* um, 10 \* um\)",
    ):
        simulate_psf(design, depths=(-10.0, 0.0, 10.0), crop=64)
    with pytest.raises(ValueError, match=r"got \(0\.001\) m.*Fix: give depths in metres"):
        simulate_psf(design, depths=(1e-3,), crop=64)


def test_a_design_whose_own_range_is_deeper_than_a_millimetre_keeps_it(design):
    deep = design.updated(depths=DepthSpec(depth_range_um=(-1500.0, 1500.0), depth_step_um=500.0))
    assert source_depths(deep, (1.2e-3, -1.5e-3)) == (1.2e-3, -1.5e-3)
    with pytest.raises(ValueError, match=r"within 1\.5 mm of focus"):
        source_depths(deep, (2e-3,))


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_depths_are_refused_naming_depths(design, bad):
    with pytest.raises(
        ValueError, match=r"depths must be finite numbers in metres; got \(0, (nan|inf)\) m\. Fix"
    ):
        simulate_psf(design, depths=(0.0, bad), crop=64)


def test_one_number_is_one_depth(design):
    one = simulate_psf(design, depths=5 * um, crop=32)
    listed = simulate_psf(design, depths=(5 * um,), crop=32)
    assert one.depths == (5 * um,)
    assert torch.equal(one.data, listed.data)
    assert source_depths(design, np.float64(0.0)) == (0.0,)
    assert source_depths(design, torch.tensor([0.0, 1e-5], dtype=torch.float64)) == (0.0, 1e-5)
    with pytest.raises(TypeError, match=r"depths must be numbers in metres, not text; got '10'"):
        source_depths(design, "10")


def test_depths_far_outside_the_design_range_warn_and_nearby_ones_do_not(design):
    with pytest.warns(DesignWarning, match=r"depths \(200, -150\) um lie far outside the design's depth range "
                      r"-40 \.\. 40 um \(more than 80 um beyond it\).*Fix: check that the depths are in metres"):  # fmt: skip
        assert source_depths(design, (200 * um, 0.0, -150 * um)) == (200 * um, 0.0, -150 * um)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        source_depths(design, (-120 * um, 100 * um))  # within one range width of it


def test_a_torch_dtype_is_taken_like_its_name(design):
    assert simulate_psf(design, depths=(0.0,), crop=32, dtype=torch.float64).data.dtype == torch.float64
    with pytest.raises(ValueError, match=r"dtype must be 'float32' or 'float64' \(or torch\.float32 / torch\.float64\); "
                       r"got torch\.float16\. Fix"):  # fmt: skip
        simulate_psf(design, depths=(0.0,), crop=32, dtype=torch.float16)


def test_a_preset_name_for_the_design_is_refused_with_the_call_that_loads_it():
    with pytest.raises(TypeError, match=r"design must be a Design; got the str 'flfm_guo2019'\. "
                       r"Fix: design = load_preset\('flfm_guo2019'\)"):  # fmt: skip
        simulate_psf("flfm_guo2019", depths=(0.0,), crop=32)
    with pytest.raises(
        TypeError, match=r"got the str 'mine\.json'\. Fix: design = load_design\('mine\.json'\)"
    ):
        simulate_psf("mine.json")


def test_cuda_without_a_cuda_device_is_refused_naming_device(design, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(
        ValueError, match=r"device 'cuda': no CUDA device is available here.*Fix: pass device='cpu'"
    ):
        simulate_psf(design, depths=(0.0,), crop=32, device="cuda")
    with pytest.raises(ValueError, match=r"device must be a torch device such as 'cpu' or 'cuda'; got 'gpu'"):
        simulate_psf(design, depths=(0.0,), crop=32, device="gpu")
