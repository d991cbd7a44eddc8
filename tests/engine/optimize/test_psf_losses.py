"""PSF-engineering losses: gradcheck, closed-form references and floors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.special import ndtr

from lfm_studio.engine.optimize.psf_losses import (
    _depth_derivative,
    axial_crb,
    axial_fisher_information,
    depth_dissimilarity,
    mtf_support,
)


def _stack(z=3, y=5, x=5, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand((z, y, x), generator=g, dtype=torch.float64) + 0.1).requires_grad_(True)


# ----- gradients -----


def test_gradcheck_depth_dissimilarity():
    assert torch.autograd.gradcheck(lambda p: depth_dissimilarity(p), (_stack(),))
    assert torch.autograd.gradcheck(lambda p: depth_dissimilarity(p, reduction="sum"), (_stack(4),))


def test_gradcheck_mtf_support():
    assert torch.autograd.gradcheck(
        lambda p: mtf_support(p, threshold=0.3, softness=0.05), (_stack(2, 6, 5),)
    )


@pytest.mark.parametrize("normalize", [True, False])
def test_gradcheck_fisher_and_crb(normalize):
    depths = torch.tensor([0.0, 1e-6, 2.5e-6, 3e-6], dtype=torch.float64)  # unequal steps
    assert torch.autograd.gradcheck(
        lambda p: axial_crb(p, depths, photons=500.0, background=2.0, normalize=normalize) / 1e-6,
        (_stack(4, 4, 5),),
    )


# ----- depth dissimilarity -----


def test_dissimilarity_of_identical_slices_is_the_maximum_and_of_disjoint_spots_zero():
    spot = torch.zeros(9, 9, dtype=torch.float64)
    spot[3:6, 3:6] = torch.rand(3, 3, dtype=torch.float64) + 0.5
    identical = torch.stack([spot, 2.0 * spot, 0.5 * spot])  # scale does not matter
    assert depth_dissimilarity(identical).item() == pytest.approx(1.0, abs=1e-12)
    assert depth_dissimilarity(identical, reduction="sum").item() == pytest.approx(3.0, abs=1e-12)
    disjoint = torch.zeros(3, 9, 9, dtype=torch.float64)
    disjoint[0, 0, 0], disjoint[1, 4, 4], disjoint[2, 8, 1:3] = 1.0, 3.0, 1.0
    assert depth_dissimilarity(disjoint).item() == 0.0
    # Any non-negative stack lies in between; a constant stack (the trivial answer) is the worst.
    random = torch.rand(5, 9, 9, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    assert 0.0 < depth_dissimilarity(random).item() < 1.0
    assert depth_dissimilarity(torch.ones(3, 9, 9, dtype=torch.float64)).item() == pytest.approx(1.0)


def test_dissimilarity_matches_an_explicit_pair_sum():
    stack = torch.rand(4, 6, 7, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    expected = 0.0
    for i in range(4):
        for j in range(i + 1, 4):
            a, b = stack[i].flatten().numpy(), stack[j].flatten().numpy()
            expected += float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    assert depth_dissimilarity(stack, reduction="sum").item() == pytest.approx(expected, rel=1e-12)


# ----- MTF support -----


def _gaussian(n, sigma):
    r = torch.arange(n, dtype=torch.float64) - n // 2
    g = torch.exp(-(r[:, None] ** 2 + r[None, :] ** 2) / (2 * sigma**2))
    return (g / g.sum())[None]


def test_mtf_support_of_a_delta_is_one_and_of_a_wide_gaussian_small():
    delta = torch.zeros(1, 32, 32, dtype=torch.float64)
    delta[0, 16, 16] = 1.0
    assert mtf_support(delta).item() == 1.0
    assert mtf_support(delta, softness=0.02).item() == pytest.approx(1.0, abs=1e-15)
    # A Gaussian of sigma pixels has MTF exp(-2 pi^2 sigma^2 f^2): above 0.1 for f < f_c, so
    # the support is the disc of radius f_c, a fraction (f_c / 0.5)^2 of the Nyquist disc.
    sigma = 5.0
    f_c = math.sqrt(math.log(10.0) / (2 * math.pi**2 * sigma**2))
    support = mtf_support(_gaussian(128, sigma)).item()
    assert support == pytest.approx((f_c / 0.5) ** 2, rel=0.08)
    assert support < 0.03
    # The smooth version agrees with the count when the sigmoid is sharp.
    assert mtf_support(_gaussian(128, sigma), softness=1e-4).item() == pytest.approx(support, abs=0.003)
    # A constant image (the trivial answer) transmits only DC.
    flat = torch.ones(1, 32, 32, dtype=torch.float64)
    assert mtf_support(flat).item() == pytest.approx(1.0 / int(mtf_support_band_count(32)))


def mtf_support_band_count(n: int) -> int:
    f = np.fft.fftfreq(n)
    return int(np.sum(f[:, None] ** 2 + f[None, :] ** 2 <= 0.25 * (1 + 1e-12)))


# ----- Fisher information / Cramer-Rao bound -----


def _pixel_gaussian(sigma: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-integrated normalised 2-D Gaussians ``(Z, n, n)`` and their derivative in sigma."""
    edges = np.arange(n + 1) - n / 2.0
    s = sigma[:, None]
    cdf = ndtr(edges[None, :] / s)
    pdf = np.exp(-0.5 * (edges[None, :] / s) ** 2) / math.sqrt(2 * math.pi)
    line = np.diff(cdf, axis=1)
    dline = np.diff(-pdf * edges[None, :] / s**2, axis=1)
    p = line[:, :, None] * line[:, None, :]
    dp = dline[:, :, None] * line[:, None, :] + line[:, :, None] * dline[:, None, :]
    return p, dp


def test_crb_of_a_gaussian_whose_width_grows_linearly_matches_the_closed_form():
    # sigma(z) = sigma0 + a z (pixels); without background, I(z) = N (4 a^2 / sigma^2), so
    # CRB = sigma / (2 a sqrt(N)) (continuous Gaussian: r^2 / sigma^2 is chi-square with 2 dof).
    depths = np.linspace(0.0, 20e-6, 21)
    sigma0, a, photons = 2.5, 0.1 / 1e-6, 2000.0
    sigma = sigma0 + a * depths
    p, _ = _pixel_gaussian(sigma, 48)
    crb = axial_crb(torch.from_numpy(p), torch.from_numpy(depths), photons=photons)
    expected = sigma / (2 * a * math.sqrt(photons))
    np.testing.assert_allclose(crb.numpy(), expected, rtol=0.03)


def test_fisher_with_background_matches_the_analytic_derivative():
    depths = np.linspace(-5e-6, 5e-6, 41)
    sigma = 3.0 + 0.05 / 1e-6 * (depths - depths[0]) + 2e3 * depths**2 / 1e-6  # not linear
    dsigma = 0.05 / 1e-6 + 4e3 * depths / 1e-6
    photons, background = 800.0, 3.0
    p, dp_dsigma = _pixel_gaussian(sigma, 40)
    mu = photons * p + background
    slope = photons * dp_dsigma * dsigma[:, None, None]
    expected = np.sum(slope**2 / mu, axis=(1, 2))
    got = axial_fisher_information(
        torch.from_numpy(p), torch.from_numpy(depths), photons=photons, background=background
    ).numpy()
    np.testing.assert_allclose(got, expected, rtol=0.01)
    # More background, less information; a depth-independent PSF carries none.
    noisier = axial_fisher_information(
        torch.from_numpy(p), torch.from_numpy(depths), photons=photons, background=30.0
    ).numpy()
    assert np.all(noisier < got)
    still = torch.from_numpy(np.repeat(p[:1], 5, axis=0))
    flat_depths = torch.linspace(0.0, 4e-6, 5, dtype=torch.float64)
    none = axial_fisher_information(still, flat_depths, photons=photons, background=1.0)
    assert torch.all(none < 1e-20 * got.min())  # zero up to rounding in the depth steps
    assert torch.all(axial_crb(still, flat_depths, photons=photons, background=1.0) > 1.0)  # metres


def test_depth_derivative_is_exact_for_quadratics_on_unequal_steps():
    z = torch.tensor([0.0, 1.0, 1.5, 3.0, 3.2], dtype=torch.float64)
    values = (2.0 * z**2 - z + 4.0)[:, None, None].expand(5, 2, 3)
    slope = _depth_derivative(values, z)
    assert torch.allclose(slope, (4.0 * z - 1.0)[:, None, None].expand(5, 2, 3), atol=1e-12)


def test_bad_inputs_name_the_parameter():
    stack = torch.rand(3, 4, 4, dtype=torch.float64)
    depths = torch.tensor([0.0, 1e-6, 2e-6], dtype=torch.float64)
    with pytest.raises(ValueError, match="psf must be a real tensor"):
        depth_dissimilarity(stack[0])
    with pytest.raises(ValueError, match="at least 2 depths"):
        depth_dissimilarity(stack[:1])
    with pytest.raises(ValueError, match="depths must be a strictly increasing"):
        axial_crb(stack, depths.flip(0), photons=100.0)
    with pytest.raises(ValueError, match="photons must be > 0"):
        axial_crb(stack, depths, photons=0.0)
    with pytest.raises(ValueError, match="background must be >= 0"):
        axial_crb(stack, depths, photons=10.0, background=-1.0)
    with pytest.raises(ValueError, match="threshold"):
        mtf_support(stack, threshold=1.5)
    with pytest.raises(ValueError, match="softness"):
        mtf_support(stack, softness=-1.0)
