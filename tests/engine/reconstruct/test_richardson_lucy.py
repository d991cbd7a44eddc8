"""3D Richardson-Lucy: EM monotonicity, iterate semantics, stopping, progress/cancel, dtypes, scale."""

from __future__ import annotations

import threading

import pytest
import torch

from lfm_studio.engine.progress import CancelledError
from lfm_studio.engine.reconstruct import poisson_nll, richardson_lucy, richardson_lucy_iterates
from lfm_studio.engine.simulation import camera_of, light_field_image
from tests.engine.reconstruct.conftest import bead_phantom

SYSTEMS = ["fourier", "conventional"]
SEEDS = {"fourier": 6, "conventional": 2}  # beads at several depths (see test_beads.py)


def _noisy_photons(system, truth, *, photons=2e5, seed=5):
    """Electrons plus read-noise variance (Snyder's shift): y = (counts - offset) / gain + s^2, b = s^2."""
    camera = camera_of(system.design)
    counts, _ = light_field_image(system.setup64, truth, camera, photons=photons, seed=seed)
    variance = camera.read_noise**2
    return ((counts - camera.baseline) / camera.gain + variance).clamp_min(0.0), variance


@pytest.mark.parametrize("name", SYSTEMS)
def test_poisson_nll_never_increases(name, request):
    system = request.getfixturevalue(name)
    truth = bead_phantom(system.setup, count=3, seed=SEEDS[name]).data.double()
    image, b = _noisy_photons(system, truth)
    projector = system.setup64.projector
    iterates = list(richardson_lucy_iterates(projector, image, background=b, iterations=25, track_nll=True))
    start = torch.full(projector.volume_shape, 1.0, dtype=torch.float64)
    flux = float((image - b).sum()) / float(projector.adjoint(torch.ones_like(image)).sum())
    nll = [poisson_nll(projector, start * flux, image, background=b)] + [it.nll for it in iterates]
    # EM: NLL(x_k+1) <= NLL(x_k) exactly; float64 sums of ~1e4 terms of size ~1e2 round at ~1e-12 relative.
    for k in range(len(nll) - 1):
        assert nll[k + 1] <= nll[k] + 1e-12 * abs(nll[k]), (
            f"NLL rose at iteration {k + 1}: {nll[k]} -> {nll[k + 1]}"
        )
    assert nll[-1] < nll[0] - 1e-3 * abs(nll[0])  # and it does go down (the test can fail)
    # The reported NLL is the one of the yielded estimate.
    assert iterates[-1].nll == pytest.approx(
        poisson_nll(projector, iterates[-1].estimate, image, background=b), rel=1e-12
    )


def test_iterates_are_fresh_tensors_with_their_relative_change(fourier):
    truth = bead_phantom(fourier.setup, count=3, seed=6).data
    image = fourier.setup.projector.forward(truth).clamp_min(0.0)
    kept, copies = [], []
    previous = None
    for it in richardson_lucy_iterates(fourier.setup.projector, image, iterations=6):
        kept.append(it)
        copies.append(it.estimate.clone())
        assert it.alpha == 0.0 and it.nll is None and bool((it.estimate >= 0).all())
        if previous is not None:
            expected = float((it.estimate - previous).double().norm() / previous.double().norm())
            # Norms are accumulated in float32 (4e4 squares): ~1e-5 relative; measured 2.5e-6.
            assert it.relative_change == pytest.approx(expected, rel=1e-4)
        previous = it.estimate
    assert [it.index for it in kept] == [1, 2, 3, 4, 5, 6]
    for it, copy in zip(kept, copies, strict=True):  # later iterations never write into earlier ones
        assert torch.equal(it.estimate, copy)


def test_rtol_stops_at_the_first_small_change(fourier):
    truth = bead_phantom(fourier.setup, count=3, seed=6).data
    image = fourier.setup.projector.forward(truth).clamp_min(0.0)
    full = list(richardson_lucy_iterates(fourier.setup.projector, image, iterations=12))
    rtol = 0.5 * (full[5].relative_change + full[6].relative_change)  # between iterations 6 and 7
    stopped = list(richardson_lucy_iterates(fourier.setup.projector, image, iterations=12, rtol=rtol))
    first_below = next(it.index for it in full if it.relative_change < rtol)
    assert stopped[-1].index == first_below < 12
    assert torch.equal(stopped[-1].estimate, full[first_below - 1].estimate)


def test_default_start_is_flux_matched_and_rl_keeps_the_flux(conventional):
    projector = conventional.setup64.projector
    truth = bead_phantom(conventional.setup, count=3, seed=2).data.double()
    image = projector.forward(truth).clamp_min(0.0)
    level = float(image.sum()) / float(projector.adjoint(torch.ones_like(image)).sum())
    default = next(iter(richardson_lucy_iterates(projector, image, iterations=1)))
    explicit = richardson_lucy(
        projector, image, iterations=1, initial=torch.full(projector.volume_shape, level)
    )
    assert torch.allclose(default.estimate, explicit, rtol=1e-12, atol=0.0)
    # With b = 0 an RL step keeps sum(A x) = sum(y) (float64 rounding of the sums: 1e-12).
    assert float(projector.forward(default.estimate).sum()) == pytest.approx(float(image.sum()), rel=1e-12)


def test_progress_is_reported_and_cancel_leaves_earlier_iterates_intact(fourier):
    truth = bead_phantom(fourier.setup, count=3, seed=6).data
    image = fourier.setup.projector.forward(truth).clamp_min(0.0)
    stop, calls = threading.Event(), []

    def progress(done, total, message):
        calls.append((done, total))
        if done == 3:
            stop.set()

    got = []
    with pytest.raises(CancelledError):
        for it in richardson_lucy_iterates(
            fourier.setup.projector, image, iterations=10, progress=progress, cancel=stop
        ):
            got.append((it, it.estimate.clone()))
    assert calls == [(0, 10), (1, 10), (2, 10), (3, 10)]
    assert [it.index for it, _ in got] == [1, 2, 3]
    assert all(torch.equal(it.estimate, copy) for it, copy in got)
    with pytest.raises(CancelledError):  # the plain function raises and returns nothing
        richardson_lucy(fourier.setup.projector, image, iterations=10, cancel=lambda: True)
    done = []
    richardson_lucy(fourier.setup.projector, image, iterations=2, progress=lambda d, t, m: done.append(d))
    assert done == [0, 1, 2]


@pytest.mark.parametrize("name", SYSTEMS)
@pytest.mark.parametrize("acceleration", [None, "biggs-andrews"])
def test_float32_and_float64_agree(name, acceleration, request):
    system = request.getfixturevalue(name)
    truth = bead_phantom(system.setup, count=3, seed=SEEDS[name]).data.double()
    image = system.setup64.projector.forward(truth).clamp_min(0.0)
    single = richardson_lucy(system.setup.projector, image.float(), iterations=30, acceleration=acceleration)
    double = richardson_lucy(system.setup64.projector, image, iterations=30, acceleration=acceleration)
    assert single.dtype == torch.float32 and double.dtype == torch.float64
    # float32 FFT/conv rounding (~1e-7 per pass) is carried multiplicatively through 30 updates;
    # measured 2e-5 (plain) and 9e-5 (accelerated) relative L2; bound 5e-4.
    error = float((single.double() - double).norm() / double.norm())
    assert error < 5e-4


@pytest.mark.parametrize("scale", [1e-25, 1e25])
def test_float32_result_scales_with_the_data_relative_epsilon(fourier, scale):
    # An absolute epsilon (1e-12) would swamp A x ~ 1e-25 and clip nothing at 1e25; the relative floor
    # makes RL exactly scale-covariant. Measured 2e-7 (float32 rounding); bound 1e-5.
    truth = bead_phantom(fourier.setup, count=3, seed=6).data
    image = fourier.setup.projector.forward(truth).clamp_min(0.0)
    b = 0.5 * float(image.mean())
    reference = richardson_lucy(fourier.setup.projector, image, iterations=8, background=b)
    scaled = richardson_lucy(fourier.setup.projector, image * scale, iterations=8, background=b * scale)
    assert bool(torch.isfinite(scaled).all())
    error = float((scaled.double() / scale - reference.double()).norm() / reference.double().norm())
    assert error < 1e-5


def test_sparse_image_with_dark_pixels_gives_finite_non_negative_estimates(conventional):
    projector = conventional.setup.projector
    image = torch.zeros(projector.image_shape)
    image[40, 50] = 7.0  # one photon-carrying pixel, all else zero
    for acceleration in (None, "biggs-andrews"):
        estimate = richardson_lucy(projector, image, iterations=20, acceleration=acceleration)
        assert bool(torch.isfinite(estimate).all()) and bool((estimate >= 0).all())
        # RL keeps the counts (b = 0): float32 sums of 3e3 values, 1e-5 relative.
        assert float(projector.forward(estimate).sum()) == pytest.approx(7.0, rel=1e-5)


def test_estimates_never_hold_denormal_numbers(conventional):
    # Denormal float32 values (< 1.2e-38) make CPU arithmetic 10-100x slower; RL flushes them to 0.
    projector = conventional.setup.projector
    truth = bead_phantom(conventional.setup, count=3, seed=2).data
    image = projector.forward(truth).clamp_min(0.0)
    start = torch.ones(projector.volume_shape)
    start[0, :5] = 1e-40  # denormal in float32
    tiny = torch.finfo(torch.float32).tiny
    for it in richardson_lucy_iterates(projector, image, iterations=3, initial=start):
        assert int(((it.estimate > 0) & (it.estimate < tiny)).sum()) == 0
    assert float(it.estimate[0, :5].abs().max()) == 0.0
