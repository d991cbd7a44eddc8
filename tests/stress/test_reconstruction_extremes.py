"""Reconstruction at the edges of float32 and of the regularisation: Wiener at SNR -> 0 and
-> infinity, Richardson-Lucy on all-zero, near-empty and extreme-range images, and photon
budgets from 1 to 1e6 per pixel through the camera.
"""

from __future__ import annotations

import itertools
import math

import pytest
import torch

from lfm_studio.engine.operators import ShiftInvariantProjector
from lfm_studio.engine.optics.camera import Camera, simulate_sensor
from lfm_studio.engine.reconstruct import (
    poisson_nll,
    richardson_lucy,
    richardson_lucy_iterates,
    wiener,
    wiener_butterworth_backprojector,
)
from tests.stress.levels import cases


def _projector(dtype: torch.dtype, *, seed: int = 0) -> ShiftInvariantProjector:
    """3 depths of 48 x 48 PSFs (Gaussian spots of growing width at three offsets), volume 3 x 21 x 21."""
    y, x = torch.meshgrid(torch.arange(48.0) - 24, torch.arange(48.0) - 24, indexing="ij")
    gen = torch.Generator().manual_seed(seed)
    psf = torch.zeros(3, 48, 48, dtype=torch.float64)
    for z, width in enumerate((1.0, 2.0, 3.5)):
        for cy, cx in ((-10, -8), (0, 9), (11, -2)):
            psf[z] += torch.exp(-((y - cy) ** 2 + (x - cx) ** 2) / (2 * width**2))
    psf += 1e-3 * torch.rand(psf.shape, generator=gen, dtype=torch.float64)
    return ShiftInvariantProjector((psf / psf.sum()).to(dtype), (21, 21))


def _beads(projector, values=(100.0, 50.0, 200.0)) -> torch.Tensor:
    volume = torch.zeros(projector.volume_shape, dtype=projector.dtype)
    for z, value in enumerate(values):
        volume[z, 5 + 4 * z, 15 - 3 * z] = value
    return volume


DTYPES = [torch.float32, torch.float64]
IDS = ["f32", "f64"]


# --- Wiener at SNR -> 0 and SNR -> infinity ------------------------------------------------
SNRS = cases([1e-30, 1e-12, 1.0, 1e12, 1e30], [1e-20, 1e-6, 1e6, 1e20])


@pytest.mark.parametrize("dtype", DTYPES, ids=IDS)
def test_wiener_is_finite_over_the_whole_snr_range_and_meets_both_limits(dtype):
    projector = _projector(dtype)
    image = projector.forward(_beads(projector))
    results = {snr: wiener(projector, image, snr=snr) for snr in sorted(SNRS)}
    results[math.inf] = wiener(projector, image, snr=math.inf)
    norms = []
    for snr, result in results.items():
        assert bool(torch.isfinite(result).all()), snr
        norms.append(float(result.double().norm()))
    # More SNR, less regularisation: the solution norm never decreases (filter gain |h|^2/(|h|^2+1/SNR)).
    assert all(b >= a * (1 - 1e-6) for a, b in itertools.pairwise(norms))
    # SNR -> 0: linear in SNR (the filter tends to SNR conj(h) / M): ratio at 1e-30 and 1e-12 agrees
    # to float rounding; no underflow to 0 in float32 (values ~1e-30 stay normal numbers).
    low = results[1e-30].double() / 1e-30
    assert float((low - results[1e-12].double() / 1e-12).norm() / low.norm()) < 1e-5
    assert float(results[1e-30].abs().max()) > 0.0
    # SNR -> infinity: the finite-SNR filter converges to the pseudo-inverse (same guard threshold).
    exact = results[math.inf].double()
    error = float((results[1e30].double() - exact).norm() / exact.norm())
    assert error < (1e-5 if dtype == torch.float32 else 1e-12)


# --- Richardson-Lucy on all-zero and near-empty images ---------------------------------------
ZERO_OPTIONS = [
    {},
    {"acceleration": "biggs-andrews"},
    {"background": 0.0, "tv_weight": 0.01},
    {"background": 2.0},
]


@pytest.mark.parametrize("dtype", DTYPES, ids=IDS)
@pytest.mark.parametrize("options", ZERO_OPTIONS, ids=["plain", "accelerated", "tv", "background"])
def test_rl_on_an_all_zero_image_is_a_named_error_not_nans(dtype, options):
    projector = _projector(dtype)
    with pytest.raises(
        ValueError, match=r"image has no signal above the background: sum\(image - background\)"
    ):
        richardson_lucy(projector, torch.zeros(projector.image_shape, dtype=dtype), iterations=3, **options)


def test_rl_with_the_wiener_butterworth_backprojector_on_an_all_zero_image_is_a_named_error():
    projector = _projector(torch.float32)
    backprojector = wiener_butterworth_backprojector(projector)
    with pytest.raises(ValueError, match="image has no signal above the background"):
        richardson_lucy(
            projector, torch.zeros(projector.image_shape), iterations=3, backprojector=backprojector
        )


# One photon-scale pixel, from 1 count down to 1e-30 counts (a float32 normal number):
# the estimate stays finite and >= 0 and keeps the counts (RL preserves sum(A x) = sum(y) for b = 0).
SINGLE = cases([1.0, 1e-30], [1e-20, 1e-10, 1e10])


@pytest.mark.parametrize("value", SINGLE, ids=lambda v: f"{v:g}")
@pytest.mark.parametrize("acceleration", [None, "biggs-andrews"], ids=["plain", "accelerated"])
def test_rl_on_a_single_bright_pixel_stays_finite_non_negative_and_keeps_the_counts(value, acceleration):
    projector = _projector(torch.float32)
    image = torch.zeros(projector.image_shape)
    image[20, 30] = value
    estimate = richardson_lucy(projector, image, iterations=20, acceleration=acceleration)
    assert bool(torch.isfinite(estimate).all()) and float(estimate.min()) >= 0.0
    assert float(projector.forward(estimate).double().sum()) == pytest.approx(value, rel=1e-4)


# float32 dynamic range: RL is scale-covariant, RL(c y) = c RL(y); the relative floors keep it so
# from c = 1e-30 (A x ~ 1e-33, near float32's smallest normal 1.2e-38) to c = 1e30 (sums ~1e34,
# squares overflow: the engine's norms fall back to float64). Measured ~2e-7; bound 1e-5.
SCALES = cases([1e-30, 1e30], [1e-33, 1e-20, 1e20, 1e33])


@pytest.mark.parametrize("scale", SCALES, ids=lambda v: f"{v:g}")
def test_rl_in_float32_is_scale_covariant_across_the_float32_range(scale):
    projector = _projector(torch.float32)
    image = projector.forward(_beads(projector)).clamp_min(0.0)
    reference = richardson_lucy(projector, image, iterations=10)
    scaled = richardson_lucy(projector, image * scale, iterations=10)
    assert bool(torch.isfinite(scaled).all()) and float(scaled.min()) >= 0.0
    error = float((scaled.double() / scale - reference.double()).norm() / reference.double().norm())
    assert error < 1e-5


@pytest.mark.parametrize("scale", [1e-35, 1e-36])
def test_rl_in_float32_keeps_every_normal_voxel_when_the_data_near_the_denormal_range(scale):
    # Image max ~1e-35: the dimmest estimate voxels (~1e-42) lie below float32's smallest normal
    # number (1.2e-38) and are 0 in the result (no denormals). Before RL ran on data rescaled
    # to ~1, voxels dipping below it during the iterations were flushed for good, which cost the
    # voxels that stay normal 8e-5 (1e-35) and 2e-3 (1e-36) of relative error; now ~3e-7.
    projector = _projector(torch.float32)
    scaled_image = projector.forward(_beads(projector)).clamp_min(0.0) * scale
    image = (scaled_image.double() / scale).float()  # the same data (dark pixels rounded alike)
    reference = richardson_lucy(projector, image, iterations=10).double() * scale
    scaled = richardson_lucy(projector, scaled_image, iterations=10).double()
    normal = reference >= torch.finfo(torch.float32).tiny
    assert 0 < int(normal.sum()) < normal.numel()
    error = float(((scaled - reference) * normal).norm() / (reference * normal).norm())
    assert error < 1e-5
    assert bool((scaled[~normal] == 0).all())


@pytest.mark.parametrize("exponent", [-100, -50, 50, 100])  # image and estimates stay normal
def test_rl_scaled_by_a_power_of_two_is_exactly_scaled(exponent):
    # The data are divided by a power of two inside RL and the estimates multiplied back, both
    # exact in binary floating point: RL(2^e y) is 2^e RL(y) bit for bit, and the reported NLL is
    # the data-unit NLL of the returned estimate.
    projector = _projector(torch.float32)
    image = projector.forward(_beads(projector)).clamp_min(0.0)
    factor = 2.0**exponent
    reference = richardson_lucy(projector, image, iterations=5)
    iterates = list(richardson_lucy_iterates(projector, image * factor, iterations=5, track_nll=True))
    assert torch.equal(iterates[-1].estimate, reference * factor)
    nll = poisson_nll(projector, iterates[-1].estimate, image * factor)
    assert iterates[-1].nll == pytest.approx(nll, rel=1e-9)


def test_rl_in_float32_resolves_beads_eight_decades_apart():
    # A 1e6 bead next to a 1e-2 bead (float32 keeps ~7 decades per value, but each pixel is
    # dominated by one bead): finite, non-negative, and the faint bead's depth keeps its counts.
    projector = _projector(torch.float32)
    volume = _beads(projector, values=(1e6, 0.0, 1e-2))
    image = projector.forward(volume).clamp_min(0.0)
    estimate = richardson_lucy(projector, image, iterations=50)
    assert bool(torch.isfinite(estimate).all()) and float(estimate.min()) >= 0.0
    predicted = projector.forward(estimate).double()
    assert float(predicted.sum()) == pytest.approx(float(image.double().sum()), rel=1e-4)
    assert float(estimate[0].double().sum()) == pytest.approx(1e6, rel=0.05)


# --- photon budgets ------------------------------------------------------------------------------
BUDGETS = cases([1.0, 100.0, 1e6], [3.0, 1e4, 1e5])


@pytest.mark.parametrize("photons", BUDGETS, ids=lambda v: f"{v:g}")
def test_photon_budgets_from_one_to_a_million_per_pixel_keep_poisson_statistics(photons):
    # 128 x 128 pixels of mean m: the sample mean is within 5 sigma = 5 sqrt(m / N) of m, the
    # variance within 5 sqrt(2 / N) (relative; Poisson: var = m) plus the 1/12 of rounding to ADU.
    n = 128 * 128
    camera = Camera(pixel_pitch=6.5e-6, bit_depth=32)
    power = torch.full((128, 128), 0.25)
    counts = simulate_sensor(power, camera, photons_per_unit=4.0 * photons, generator=7).double()
    assert bool(torch.isfinite(counts).all()) and float(counts.min()) >= 0.0
    assert float(counts.max()) < camera.max_count
    assert abs(float(counts.mean()) - photons) < 5.0 * math.sqrt(photons / n)
    assert float(counts.var()) == pytest.approx(photons, rel=5.0 * math.sqrt(2.0 / n), abs=0.5)
    assert bool((counts == counts.round()).all())
