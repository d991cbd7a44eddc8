"""Faster RL (Biggs-Andrews, Wiener-Butterworth back projector) and TV-regularised RL."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.reconstruct import (
    FilteredBackProjector,
    accelerated_rl_options,
    richardson_lucy,
    richardson_lucy_iterates,
    wiener_butterworth_backprojector,
)
from lfm_studio.engine.reconstruct.accelerated import ALPHA_MAX, LOG_STEP_MAX, GeometricExtrapolation
from lfm_studio.engine.reconstruct.fourier_geometry import radial_frequency
from lfm_studio.engine.reconstruct.tikhonov import otf_power
from lfm_studio.engine.reconstruct.total_variation import DIVERGENCE_BOUND, tv_denominator, tv_divergence
from tests.engine.reconstruct.conftest import bead_phantom, psnr


@pytest.fixture(scope="module")
def beads_problem(fourier):
    truth = bead_phantom(fourier.setup, count=3, seed=6).data
    image = fourier.setup.projector.forward(truth).clamp_min(0.0)
    plain = list(richardson_lucy_iterates(fourier.setup.projector, image, iterations=30))
    return truth, image, psnr(truth, plain[-1].estimate)


def _iterations_to_reach(target: float, truth, iterates) -> int | None:
    return next((it.index for it in iterates if psnr(truth, it.estimate) >= target), None)


@pytest.mark.parametrize(
    ("options", "at_most"),
    [
        # Measured on this system (3 beads, noise-free): plain RL needs 30 iterations for its PSNR;
        # Biggs-Andrews 14, Wiener-Butterworth (alpha 1) 17, both together 13, geometric 10,
        # geometric + WB alpha 0.7 9; accelerated_rl_options is geometric alone. Bounds leave room for rounding
        # differences; the geometric bounds also sit below Biggs-Andrews' measured 14.
        ({"acceleration": "biggs-andrews"}, 18),
        ({"backprojector": "wb"}, 22),
        ({"backprojector": "wb", "acceleration": "biggs-andrews"}, 18),
        ({"acceleration": "geometric"}, 12),
        ({"recommended": True}, 11),
    ],
    ids=["biggs-andrews", "wiener-butterworth", "both", "geometric", "accelerated-rl-options"],
)
def test_faster_methods_reach_plain_rl_30_quality_in_fewer_iterations(
    fourier, beads_problem, options, at_most
):
    truth, image, target = beads_problem
    projector = fourier.setup.projector
    if options.get("backprojector") == "wb":
        options = {**options, "backprojector": wiener_butterworth_backprojector(projector)}
    if options.get("recommended"):
        options = accelerated_rl_options(projector)
    iterates = richardson_lucy_iterates(projector, image, iterations=30, **options)
    reached = _iterations_to_reach(target, truth, iterates)
    assert reached is not None and reached <= at_most, f"reached plain-30 PSNR {target:.2f} dB at {reached}"


def test_biggs_andrews_extrapolates_and_keeps_estimates_non_negative(fourier, beads_problem):
    _, image, _ = beads_problem
    iterates = list(
        richardson_lucy_iterates(fourier.setup.projector, image, iterations=8, acceleration="biggs-andrews")
    )
    alphas = [it.alpha for it in iterates]
    assert alphas[:2] == [0.0, 0.0]  # no history for the first two updates
    assert all(0.0 <= a < 1.0 for a in alphas) and max(alphas) > 0.3
    assert all(bool((it.estimate >= 0).all()) for it in iterates)


def test_geometric_extrapolation_continues_a_geometric_sequence():
    # Voxels multiplied by a constant factor r per RL step (the tail of an RL run): the log
    # steps are equal, alpha reaches its cap and the prediction is x_k (x_k / x_(k-1))^alpha,
    # i.e. log x extrapolated linearly (x_k / x_(k-1) = r^(1 + alpha) once extrapolating).
    ratios = torch.tensor([0.5, 1.0, 1.25, 3.0], dtype=torch.float64)
    extrapolation = GeometricExtrapolation()
    previous, x = None, torch.ones(4, dtype=torch.float64)
    for _ in range(3):
        point = extrapolation.predict(x)
        update = point * ratios  # an "RL step" multiplying by r
        extrapolation.record(x, point, update)
        previous, x = x, update
    point = extrapolation.predict(x)
    assert extrapolation.alpha == ALPHA_MAX
    torch.testing.assert_close(point, x * (x / previous) ** ALPHA_MAX, rtol=1e-12, atol=0.0)
    torch.testing.assert_close(
        point.log(), x.log() + ALPHA_MAX * (x.log() - previous.log()), rtol=1e-12, atol=1e-12
    )


def test_geometric_extrapolation_keeps_zeros_and_bounds_huge_steps_in_float32():
    extrapolation = GeometricExtrapolation()
    x = torch.tensor([0.0, 1e-30, 1.0, 3e30], dtype=torch.float32)
    steps = torch.tensor([1.0, 1e20, 2.0, 10.0], dtype=torch.float32)
    for _ in range(3):
        point = extrapolation.predict(x)
        update = (point * steps).clamp_max(3e38)
        extrapolation.record(x, point, update)
        x = update
    point = extrapolation.predict(x)
    assert bool(torch.isfinite(point).all()) and bool((point >= 0).all())
    assert float(point[0]) == 0.0  # RL keeps a zero voxel at zero; so does the extrapolation
    # |log step| is clipped at LOG_STEP_MAX: the 1e20x step extrapolates by at most e^8.
    assert float(point[1] / x[1]) <= math.exp(LOG_STEP_MAX) * (1 + 1e-5)


def test_accelerated_rl_options_are_geometric_with_the_matched_back_projector(fourier, conventional):
    # The Wiener-Butterworth back projector is no longer part of them: it collapsed at low light
    # (recommended.py; tests/engine/reconstruct/test_low_light_acceleration.py).
    for system in (fourier, conventional):
        assert accelerated_rl_options(system.setup.projector) == {"acceleration": "geometric"}


def test_filtered_adjoint_rejects_filters_of_the_wrong_shape(fourier):
    projector = fourier.setup.projector
    image = torch.zeros(projector.image_shape)
    with pytest.raises(ValueError, match=r"filters_t must have the shape of otf_t"):
        projector.filtered_adjoint(image, projector.otf_t[:1])


def test_matched_filter_reproduces_the_projector_adjoint(fourier):
    projector = fourier.setup64.projector
    image = torch.rand(projector.image_shape, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    matched = FilteredBackProjector(projector, projector.otf.conj().resolve_conj())
    expected = projector.adjoint(image)
    # Same embedding, same FFTs: float64 rounding only.
    assert torch.allclose(matched(image), expected, rtol=0, atol=1e-12 * float(expected.abs().max()))


def test_wiener_butterworth_filter_has_the_adjoint_dc_gain_and_gain_beta_at_the_cutoff(fourier):
    projector = fourier.setup.projector
    alpha, beta, cutoff = 1.0, 0.02, 0.25
    bp = wiener_butterworth_backprojector(projector, alpha=alpha, beta=beta, cutoff=cutoff)
    # DC: the filters equal conj(otf) there (float32 rounding of the normalisation, 1e-6).
    assert torch.allclose(bp.filters[:, 0, 0], projector.otf[:, 0, 0].conj(), rtol=1e-6)
    # |BP| summed over depths, relative to the matched DC gain, is beta (1 + alpha) on the cutoff ring.
    gain = torch.sqrt((bp.filters.abs().double() ** 2).sum(0) / otf_power(projector).max())
    radius = radial_frequency(projector)
    step = 1.0 / max(projector.fft_shape)
    ring = torch.round(radius / step) == round(cutoff / step)
    assert float(gain[ring].max()) == pytest.approx(beta * (1 + alpha), rel=1e-4)
    assert float(gain[radius > 1.5 * cutoff].max()) < 0.02 * beta  # order-8 roll-off beyond the cutoff


def test_unmatched_back_projector_needs_otfs(conventional):
    with pytest.raises(NotImplementedError, match="LensletLatticeProjector has no otf"):
        wiener_butterworth_backprojector(conventional.setup.projector)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"alpha": 0.0}, "alpha must be a finite number > 0"),
        ({"beta": 1.5}, r"beta must be in \(0, 1\)"),
        ({"order": 0}, "order must be an int >= 1"),
        ({"cutoff": 0.9}, r"cutoff must be in \(0, 0.75\]"),
    ],
)
def test_wiener_butterworth_parameter_errors(fourier, kwargs, message):
    with pytest.raises(ValueError, match=message):
        wiener_butterworth_backprojector(fourier.setup.projector, **kwargs)


def _total_variation(volume: torch.Tensor) -> float:
    return float(sum(torch.diff(volume.double(), dim=d).abs().sum() for d in range(3)))


def test_tv_regularisation_lowers_total_variation_more_with_a_larger_weight(fourier, beads_problem):
    _, image, _ = beads_problem
    noisy = torch.poisson(image * 50, generator=torch.Generator().manual_seed(3))
    tv = {}
    for weight in (0.0, 0.02, 0.05):
        estimate = richardson_lucy(fourier.setup.projector, noisy, iterations=20, tv_weight=weight)
        assert bool((estimate >= 0).all()) and bool(torch.isfinite(estimate).all())
        tv[weight] = _total_variation(estimate)
    # Measured TV ratios to plain RL: 0.87 (0.02) and 0.74 (0.05) after 20 iterations.
    assert tv[0.02] < 0.95 * tv[0.0] and tv[0.05] < 0.95 * tv[0.02]


def test_tv_divergence_is_bounded_and_the_denominator_stays_positive():
    generator = torch.Generator().manual_seed(1)
    for _ in range(5):
        volume = torch.rand((4, 9, 9), generator=generator, dtype=torch.float64) ** 4
        assert float(tv_divergence(volume).abs().max()) <= DIVERGENCE_BOUND + 1e-12
        assert float(tv_denominator(volume, 0.2).min()) >= 1 - 0.2 * DIVERGENCE_BOUND > 0
    # The maximum is attained: a checkerboard makes unit gradients that flip at every voxel.
    checker = (torch.arange(5)[:, None, None] + torch.arange(5)[None, :, None] + torch.arange(5)) % 2
    assert float(tv_divergence(checker.double()).abs().max()) >= 3.0


def test_tv_weight_out_of_range_is_rejected(fourier, beads_problem):
    _, image, _ = beads_problem
    with pytest.raises(ValueError, match=r"tv_weight must be in \[0, 0.2113\)"):
        richardson_lucy(fourier.setup.projector, image, iterations=1, tv_weight=0.25)
