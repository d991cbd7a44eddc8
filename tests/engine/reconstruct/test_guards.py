"""Named errors for bad inputs: NaN/Inf, negative, zero-photon images, all-zero PSFs, wrong shapes; a
warning for an integer image (raw camera counts where photons are expected)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector
from lfm_studio.engine.reconstruct import (
    poisson_nll,
    reconstruct_frame,
    richardson_lucy,
    richardson_lucy_iterates,
    tikhonov,
    wiener,
)
from lfm_studio.engine.reconstruct.guards import RawCountsWarning


class _ZeroProjector:
    """A projector whose PSF is all zero (nothing reaches the camera)."""

    volume_shape, image_shape = (2, 4, 4), (6, 6)
    device, dtype = torch.device("cpu"), torch.float32

    def forward(self, volume):
        return torch.zeros(self.image_shape)

    def adjoint(self, image):
        return torch.zeros(self.volume_shape)


@pytest.fixture(scope="module")
def projector(conventional):
    return conventional.setup.projector


@pytest.fixture(scope="module")
def image(projector):
    volume = torch.zeros(projector.volume_shape)
    volume[1, 15, 15] = 100.0
    return projector.forward(volume).clamp_min(0.0)


def _with(image, index, value):
    bad = image.clone()
    bad[index] = value
    return bad


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda y: _with(y, (3, 4), float("nan")), r"image contains 1 NaN/Inf value\(s\)"),
        (lambda y: _with(y, (3, 4), float("inf")), r"image contains 1 NaN/Inf value\(s\)"),
        (lambda y: _with(y, (3, 4), -2.0), r"image must be >= 0 .* 1 negative value\(s\), minimum -2"),
        (
            lambda y: torch.zeros_like(y),
            r"image has no signal above the background: sum\(image - background\) = 0",
        ),
        (lambda y: y[:-1], r"image must have shape \(114, 114\) \(Py, Px\) camera pixels; got \(113, 114\)"),
        (lambda y: y.to(torch.complex64), "image must be real"),
    ],
    ids=["nan", "inf", "negative", "zero-photons", "shape", "complex"],
)
def test_bad_images_are_rejected_by_name(projector, image, change, message):
    with pytest.raises(ValueError, match=message):
        richardson_lucy(projector, change(image), iterations=2)


def test_inputs_are_checked_when_the_iterator_is_created(projector, image):
    with pytest.raises(ValueError, match="image contains 1 NaN/Inf"):
        richardson_lucy_iterates(projector, _with(image, (0, 0), float("nan")))  # no next() needed


def test_rounding_level_negatives_are_accepted_as_zero(projector, image):
    slightly = _with(image, (3, 4), -1e-7 * float(image.max()))  # below 16 eps of float32 (1.9e-6)
    assert bool(torch.isfinite(richardson_lucy(projector, slightly, iterations=2)).all())


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"background": -1.0}, r"background must be >= 0"),
        ({"background": float("nan")}, r"background contains 1 NaN/Inf"),
        ({"background": torch.ones(3, 3)}, r"background must be a number or broadcast to the image shape"),
        ({"background": 1e6}, r"image has no signal above the background"),
        ({"initial": "zeros"}, r"initial is all zero: multiplicative updates can never leave zero"),
        ({"initial": "negative"}, r"initial must be >= 0"),
        ({"initial": torch.ones(1, 2, 3)}, r"initial must have shape \(3, 30, 30\)"),
        ({"iterations": 0}, r"iterations must be an int >= 1"),
        ({"rtol": -1.0}, r"rtol must be a finite number > 0"),
        ({"acceleration": "nesterov"}, r"acceleration must be None, 'biggs-andrews' or 'geometric'"),
        ({"tv_weight": -0.1}, r"tv_weight must be in \[0, 0.2113\)"),
    ],
)
def test_bad_options_are_rejected_by_name(projector, image, options, message):
    if options.get("initial") == "zeros":
        options = {"initial": torch.zeros(projector.volume_shape)}
    elif options.get("initial") == "negative":
        options = {"initial": -torch.ones(projector.volume_shape)}
    with pytest.raises(ValueError, match=message):
        richardson_lucy(projector, image, **options)


def test_all_zero_psf_is_a_clear_error_not_nans():
    image = torch.ones(6, 6)
    with pytest.raises(ValueError, match=r"sensitivity A\^T 1 is zero everywhere: its PSF is all zero"):
        richardson_lucy(_ZeroProjector(), image, iterations=3)
    zero_patterns = torch.zeros((2, 3, 3, 9, 9))  # a conventional projector built from empty patterns
    lattice = LensletLatticeProjector([([0, 1], zero_patterns)], 2, (4, 4), 3)
    with pytest.raises(ValueError, match="PSF is all zero"):
        richardson_lucy(lattice, torch.ones(lattice.image_shape), iterations=3)


def test_objects_without_the_projector_interface_are_a_type_error(image):
    with pytest.raises(
        TypeError,
        match=r"projector must have forward, adjoint, volume_shape, image_shape, device and dtype "
        r"\(the Projector protocol\); object has no volume_shape, image_shape, device, dtype, forward, adjoint",
    ):
        richardson_lucy(object(), image)


def test_poisson_nll_checks_its_volume(projector, image):
    with pytest.raises(ValueError, match=r"volume contains 1 NaN/Inf"):
        poisson_nll(projector, _with(torch.ones(projector.volume_shape), (0, 0, 0), float("nan")), image)


RUNS = {
    "richardson_lucy": ("image", lambda p, y: richardson_lucy(p, y, iterations=2)),
    "wiener": ("image", lambda p, y: wiener(p, y)),
    "tikhonov": ("image", lambda p, y: tikhonov(p, y)),
    "reconstruct_frame rl": ("frame", lambda p, y: reconstruct_frame(p, y, method="rl", iterations=2)),
    "reconstruct_frame wiener": ("frame", lambda p, y: reconstruct_frame(p, y, method="wiener")),
}


@pytest.mark.parametrize("run", RUNS)
@pytest.mark.parametrize(
    "as_counts",
    [lambda y: y.round().to(torch.int32), lambda y: y.round().numpy().astype(np.uint16)],
    ids=["int32 tensor", "uint16 array"],
)
def test_an_integer_image_is_reconstructed_with_one_warning_naming_the_conversion(fourier, run, as_counts):
    """Raw camera counts (uint16 ADU) are the likely integer image; the methods take photons, baseline
    removed. One warning, at the caller's line (this file), pointing at counts_to_photons."""
    name, reconstruct = RUNS[run]
    projector = fourier.setup.projector
    volume = torch.zeros(projector.volume_shape)
    volume[2, 46, 46] = 1e4
    counts = as_counts(projector.forward(volume).clamp_min(0.0) + 100.0)  # a baseline-like offset
    with pytest.warns(RawCountsWarning) as caught:
        result = reconstruct(projector, counts)
    (warning,) = [w for w in caught if w.category is RawCountsWarning]
    message = str(warning.message)
    assert (
        f"{name} has the integer dtype {'int32' if isinstance(counts, torch.Tensor) else 'uint16'}" in message
    )
    assert "counts_to_photons" in message and "photons per voxel" in message
    assert warning.filename == __file__
    assert result.dtype == torch.float32 and bool(torch.isfinite(result).all())  # reconstructed all the same


def test_a_float_image_gives_no_raw_counts_warning(fourier):
    projector = fourier.setup.projector
    volume = torch.zeros(projector.volume_shape)
    volume[2, 46, 46] = 1e4
    photons = projector.forward(volume).clamp_min(0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RawCountsWarning)
        wiener(projector, photons.double().numpy())
        wiener(projector, photons.round())  # whole numbers in a float tensor are photons
