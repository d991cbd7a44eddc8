"""Tikhonov for the conventional (lenslet-lattice) projector: per-frequency matrices, closed form, CG.

References: the projector's own convolution (``conv2d``), a dense solve of the exact normal
equations built column by column from ``forward``, the all-zero and back-projection floors.
"""

from __future__ import annotations

import gc
import weakref

import pytest
import torch

from lfm_studio.engine.image_quality import ncc
from lfm_studio.engine.memory import MemoryBudgetError
from lfm_studio.engine.operators.lattice_spectra import LatticeSpectra, lattice_tikhonov
from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector
from lfm_studio.engine.reconstruct import registry, tikhonov
from lfm_studio.engine.reconstruct.dispatch import reconstruct_frame
from tests.engine.reconstruct.conftest import bead_phantom


def _random_lattice(q: int, s: int, depths: int, lenslets=(5, 4), seed: int = 0) -> LensletLatticeProjector:
    """Non-negative random patterns, float64; depth 0 reaches 1 lenslet, the others 2 (two groups)."""
    generator = torch.Generator().manual_seed(seed)
    near = torch.rand((1, s, s, 3 * q, 3 * q), generator=generator, dtype=torch.float64)
    far = torch.rand((depths - 1, s, s, 5 * q, 5 * q), generator=generator, dtype=torch.float64)
    return LensletLatticeProjector([([0], near), (list(range(1, depths)), far)], depths, lenslets, q)


def _seeded(shape, seed: int) -> torch.Tensor:
    """Uniform [0, 1) float64 values of ``shape`` from ``seed``."""
    return torch.rand(shape, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))


def _dense(projector: LensletLatticeProjector) -> torch.Tensor:
    """``A`` as a dense matrix (image pixels x voxels), column by column from ``forward``."""
    count = int(torch.tensor(projector.volume_shape).prod())
    columns = [projector.forward(torch.eye(count, dtype=torch.float64)[i].reshape(projector.volume_shape))
               for i in range(count)]  # fmt: skip
    return torch.stack([c.reshape(-1) for c in columns], dim=1)


# (q, s, depths): C = depths s^2 against Q^2 both ways, so both closed forms and preconditioners run.
SHAPES = [(3, 1, 2), (2, 2, 3)]


@pytest.mark.parametrize(("q", "s", "depths"), SHAPES)
def test_per_frequency_matrices_reproduce_the_projector(q, s, depths):
    projector = _random_lattice(q, s, depths)
    spectra = LatticeSpectra(projector)
    volume = _seeded(projector.volume_shape, 1)
    expected = projector.forward(volume)
    assert torch.allclose(spectra.forward(volume), expected, rtol=0, atol=1e-12 * float(expected.abs().max()))
    assert torch.allclose(spectra.to_volume(spectra.volume_spectrum(volume)), volume, atol=1e-13)
    # The largest singular value over all frequencies sits at DC for non-negative patterns.
    norms = torch.linalg.matrix_norm(spectra.matrices, ord=2)
    assert float(norms.max()) == pytest.approx(float(norms[0, 0]), rel=1e-12)
    assert spectra.peak_gain2() == pytest.approx(float(norms[0, 0]) ** 2, rel=1e-12)


@pytest.mark.parametrize(("q", "s", "depths"), SHAPES)
def test_refined_tikhonov_reaches_the_dense_solution_and_the_closed_form_is_near_it(q, s, depths):
    projector = _random_lattice(q, s, depths)
    dense = _dense(projector)
    truth = _seeded(projector.volume_shape, 2)
    image = projector.forward(truth)
    mu = 1e-2
    weight = lattice_tikhonov(projector, mu).weight
    assert weight == pytest.approx(mu * LatticeSpectra(projector).peak_gain2())
    normal = dense.T @ dense + weight * torch.eye(dense.shape[1], dtype=torch.float64)
    exact = torch.linalg.solve(normal, dense.T @ image.reshape(-1)).reshape(projector.volume_shape)
    closed = tikhonov(projector, image, mu=mu)
    refined = tikhonov(projector, image, mu=mu, refine=60)

    def error(x):
        return float((x - exact).norm() / exact.norm())

    assert error(refined) < 1e-8
    # The closed form treats the lattice FFT grid as the world (the camera sees only its lenslets):
    # nearer the exact solution than the zero volume (error 1), and a few preconditioned CG steps
    # close most of the gap.
    assert error(closed) < 0.6  # measured 0.54 on these 5 x 4 lenslets (reach 2)
    assert error(tikhonov(projector, image, mu=mu, refine=3)) < error(closed) / 10  # measured 0.034


def test_the_solver_is_kept_per_projector_and_mu_and_freed_with_the_projector():
    projector = _random_lattice(3, 1, 2)
    first = lattice_tikhonov(projector, 1e-3)
    assert lattice_tikhonov(projector, 1e-3) is first
    other = lattice_tikhonov(projector, 1e-2)
    assert other is not first and other.mu == 1e-2 and other.spectra is first.spectra
    kept = weakref.ref(other)
    del projector, first, other
    gc.collect()
    assert kept() is None  # the cache holds the projector weakly, and the solver does not hold it


def test_bad_mu_and_too_large_matrices_are_refused_by_name():
    projector = _random_lattice(3, 1, 2)
    for mu in (0.0, -1.0, float("inf")):
        with pytest.raises(
            ValueError, match=r"mu must be finite and > 0 for a conventional.*Fix: e\.g\. mu=1e-3"
        ):
            tikhonov(projector, torch.ones(projector.image_shape, dtype=torch.float64), mu=mu)
    with pytest.raises(MemoryBudgetError, match=r"max_bytes=.*Nothing was allocated. Fix: fewer depths"):
        LatticeSpectra(projector, max_bytes=1000)


def test_gradients_reach_the_frame_through_the_lattice_closed_form():
    projector = _random_lattice(2, 2, 3, lenslets=(3, 3))
    weights = _seeded(projector.volume_shape, 3)
    frame = _seeded(projector.image_shape, 4)
    method = registry.get("tikhonov")

    def loss(y):
        return (method(projector, y, {"snr": 100.0}) * weights).sum()

    assert torch.autograd.gradcheck(loss, (frame.requires_grad_(True),), eps=1e-6, atol=1e-6)


def test_tikhonov_on_the_conventional_system_beats_the_floors(conventional):
    setup = conventional.setup64
    projector = setup.projector
    assert registry.get("tikhonov").supports(projector) and not registry.get("wiener").supports(projector)
    truth = bead_phantom(setup, count=3, seed=2).data.double()
    image = projector.forward(truth)
    volume = reconstruct_frame(projector, image, method="tikhonov")  # snr 1000
    back = projector.adjoint(image)
    assert volume.shape == truth.shape and bool(torch.isfinite(volume).all())
    assert float(ncc(truth, torch.zeros_like(truth))) == 0.0
    assert float(ncc(truth, volume)) > 0.5  # measured 0.60; back-projection 0.15
    assert float(ncc(truth, volume)) > 2 * float(ncc(truth, back))
