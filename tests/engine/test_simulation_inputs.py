"""Bad input to the simulation pipeline (simulate_psf, light_field_image, make_phantom) is refused
at once, naming the parameter, the value and the fix; questionable input warns."""

from __future__ import annotations

import math
import re
import warnings

import numpy as np
import pytest
import torch

from lfm_studio.engine.design import DepthSpec, DesignWarning, load_preset
from lfm_studio.engine.optics.camera import SaturationWarning
from lfm_studio.engine.simulation import (
    camera_of,
    imaging_setup,
    light_field_image,
    make_phantom,
    photons_per_unit,
    simulate_psf,
    source_depths,
)
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
    far = (
        r"depths \(200, -150\) um lie far outside the design's depth range -40 \.\. 40 um \(more than 80 um "
        r"beyond it\).*Fix: check that the depths are in metres"
    )
    with pytest.warns(DesignWarning, match=far):
        assert source_depths(design, (200 * um, 0.0, -150 * um)) == (200 * um, 0.0, -150 * um)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        source_depths(design, (-120 * um, 100 * um))  # within one range width of it


def test_a_torch_dtype_is_taken_like_its_name(design):
    assert simulate_psf(design, depths=(0.0,), crop=32, dtype=torch.float64).data.dtype == torch.float64
    refused = (
        r"dtype must be 'float32' or 'float64' \(or torch\.float32 / torch\.float64\); got torch\.float16\."
    )
    with pytest.raises(ValueError, match=refused):
        simulate_psf(design, depths=(0.0,), crop=32, dtype=torch.float16)


def test_a_preset_name_for_the_design_is_refused_with_the_call_that_loads_it():
    refused = (
        r"design must be a Design; got the str 'flfm_guo2019'\. Fix: design = load_preset\('flfm_guo2019'\)"
    )
    with pytest.raises(TypeError, match=refused):
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


@pytest.fixture(scope="module")
def scene(design):
    setup = imaging_setup(simulate_psf(design, depths=(-10 * um, 0.0, 10 * um), crop=128))
    volume, _ = make_phantom("beads", setup, seed=1, count=5)
    return setup, volume, camera_of(design)


def test_a_negative_volume_is_refused_naming_volume_and_its_minimum(scene):
    # It used to spread the photons over the FFT round-off of a clamped-to-zero image.
    setup, volume, camera = scene
    with pytest.raises(
        ValueError,
        match=r"volume must be >= 0 .*got 5 negative value\(s\), minimum -1\. Fix: a volume is the light "
        r"emitted per voxel: clip it with volume\.clamp\(min=0\)",
    ):
        light_field_image(setup, -volume, camera, photons=1e6, seed=1)


def test_a_volume_without_light_is_refused_when_photons_are_asked_for(scene):
    setup, volume, camera = scene
    with pytest.raises(
        ValueError,
        match=r"volume puts no light on the camera \(volume sum 0, .*photons=1e\+06 cannot be placed.*"
        r"Fix: give a volume "
        r"with emitters inside the projector's field",
    ):
        light_field_image(setup, torch.zeros_like(volume), camera, photons=1e6, seed=1)
    counts, expected = light_field_image(setup, torch.zeros_like(volume), camera, photons=None, seed=1)
    assert float(counts.abs().sum()) == 0.0 and counts is expected  # noise-free: a dark image is right


def test_a_numpy_volume_gives_the_tensor_volume_image(scene):
    setup, volume, camera = scene
    from_array = light_field_image(setup, volume.numpy().astype(np.float64), camera, photons=1e6, seed=3)
    from_tensor = light_field_image(setup, volume, camera, photons=1e6, seed=3)
    assert all(torch.equal(a, b) for a, b in zip(from_array, from_tensor, strict=True))


def test_saturating_photons_warn_with_the_clipped_pixels_and_the_largest_safe_budget(scene):
    setup, volume, camera = scene
    assert camera.full_well == 30000.0 and camera.saturation_electrons == 30000.0  # the preset's camera
    with pytest.warns(SaturationWarning) as caught:
        counts, expected = light_field_image(setup, volume, camera, photons=1e12, seed=1)
    text = str(caught[0].message)
    electrons = expected.double() * photons_per_unit(expected, 1e12) * camera.quantum_efficiency
    over = int((electrons > camera.full_well).sum())
    assert 0 < over < counts.numel()
    assert text.startswith(
        f"photons=1e+12 saturates the camera: {over} of {counts.numel()} pixels expect more than 30000 e- "
        "(the full well, 30000 e-)"
    )
    safe = float(
        re.search(r"Fix: photons <= (\S+) keeps the brightest pixel below saturation", text).group(1)
    )
    exact = 1e12 * camera.full_well / float(electrons.max())
    assert 0.99 * exact < safe <= exact  # rounded down to 3 digits
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        light_field_image(setup, volume, camera, photons=safe, seed=1)


@pytest.mark.parametrize("count", [0, -3, 2.5])
def test_a_bead_phantom_needs_at_least_one_bead(scene, count):
    setup, _, _ = scene
    with pytest.raises(
        ValueError, match=rf"count must be an int >= 1 .*; got {count}\. Fix: count=1 or more, or count=None"
    ):
        make_phantom("beads", setup, seed=1, count=count)
