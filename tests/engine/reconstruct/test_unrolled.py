"""Unrolled Richardson-Lucy: a dense-matrix reference, its invariants, gradients, named errors."""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.reconstruct.unrolled import richardson_lucy_unrolled

F64 = torch.float64


class _Dense:
    """A projector from an explicit non-negative matrix ``(pixels, voxels)``."""

    def __init__(
        self, matrix: torch.Tensor, volume_shape: tuple[int, int, int], image_shape: tuple[int, int]
    ):
        self.matrix, self.volume_shape, self.image_shape = matrix, volume_shape, image_shape

    def forward(self, volume: torch.Tensor) -> torch.Tensor:
        return (self.matrix @ volume.reshape(-1)).reshape(self.image_shape)

    def adjoint(self, image: torch.Tensor) -> torch.Tensor:
        return (self.matrix.T @ image.reshape(-1)).reshape(self.volume_shape)


def _case(seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    matrix = torch.rand(20, 12, generator=gen, dtype=F64) ** 3
    projector = _Dense(matrix, (3, 2, 2), (4, 5))
    truth = torch.rand(3, 2, 2, generator=gen, dtype=F64) + 0.2
    return projector, truth, projector.forward(truth)


def test_matches_a_hand_written_dense_richardson_lucy():
    projector, _, image = _case()
    a, y = projector.matrix, image.reshape(-1)
    x = torch.full((12,), float(y.sum() / (a @ torch.ones(12, dtype=F64)).sum()), dtype=F64)
    for _ in range(4):
        x = x * (a.T @ (y / (a @ x))) / a.sum(0)
    result = richardson_lucy_unrolled(projector, image, 4, eps=1e-300)
    assert torch.allclose(result.reshape(-1), x, rtol=1e-12, atol=0)


def test_flux_is_kept_the_truth_is_a_fixed_point_and_the_likelihood_rises():
    projector, truth, image = _case(1)
    sensitivity = projector.adjoint(torch.ones_like(image))
    previous = None
    for iterations in range(1, 6):
        x = richardson_lucy_unrolled(projector, image, iterations)
        assert float((x * sensitivity).sum()) == pytest.approx(float(image.sum()), rel=1e-10)
        estimate = projector.forward(x)
        nll = float((estimate - image * torch.log(estimate)).sum())
        assert previous is None or nll <= previous + 1e-12
        previous = nll
    fixed = richardson_lucy_unrolled(projector, image, 3, initial=truth)
    assert torch.allclose(fixed, truth, rtol=1e-9)
    assert torch.equal(richardson_lucy_unrolled(projector, image, 0, initial=truth), truth)


def test_gradcheck_through_the_image_and_the_matrix():
    projector, _, image = _case(2)
    matrix = projector.matrix.clone().requires_grad_()
    weights = torch.rand(3, 2, 2, generator=torch.Generator().manual_seed(3), dtype=F64)

    def loss(m, y):
        return (weights * richardson_lucy_unrolled(_Dense(m, (3, 2, 2), (4, 5)), y, 3)).sum()

    assert torch.autograd.gradcheck(loss, (matrix, image.clone().requires_grad_()))


def test_named_errors():
    projector, truth, image = _case()
    with pytest.raises(ValueError, match="iterations must be an integer >= 0; got -1"):
        richardson_lucy_unrolled(projector, image, -1)
    with pytest.raises(ValueError, match="iterations must be an integer >= 0; got True"):
        richardson_lucy_unrolled(projector, image, True)
    with pytest.raises(ValueError, match="eps must be > 0"):
        richardson_lucy_unrolled(projector, image, 1, eps=0.0)
    with pytest.raises(ValueError, match=r"initial must have the projector's volume shape \(3, 2, 2\)"):
        richardson_lucy_unrolled(projector, image, 1, initial=truth[:2])


def test_counts_where_the_model_predicts_no_light_do_not_blow_up_the_volume():
    # A float32 FFT projector whose PSF lights only the centre of a 96^2 sensor: elsewhere A x is a
    # rounding error (even negative), while the image has counts everywhere (read noise). With an
    # absolute eps only, y / (A x + eps) reached 1e12 there and the volume 8e22 after 6 steps; with
    # the production solver's floors both agree (the floors differ by at most a power of two).
    from lfm_studio.engine.operators import ShiftInvariantProjector
    from lfm_studio.engine.reconstruct.richardson_lucy import richardson_lucy

    n = 96
    r = torch.arange(n) - n // 2
    psf = torch.zeros(3, n, n)
    for z in range(3):
        spot = torch.exp(-(r[:, None] ** 2 + r[None, :] ** 2) / (2 * (1.5 + z) ** 2))
        psf[z] = spot * (spot > 1e-6)
    projector = ShiftInvariantProjector(psf, (8, 8))
    truth = torch.zeros(3, 8, 8)
    truth[1, 3, 4], truth[0, 5, 2] = 100.0, 50.0
    noise = torch.rand((n, n), generator=torch.Generator().manual_seed(0))
    image = projector.forward(truth).clamp_min(0.0) + noise
    lit = projector.forward(torch.ones(3, 8, 8))
    assert int((lit.abs() < 1e-6 * lit.max()).sum()) > n * n // 2  # most pixels see no light
    unrolled = richardson_lucy_unrolled(projector, image, 6)
    production = richardson_lucy(projector, image, iterations=6)
    assert float(unrolled.max()) < 10 * float(truth.max())
    assert float((unrolled - production).abs().max() / production.max()) < 2e-3
