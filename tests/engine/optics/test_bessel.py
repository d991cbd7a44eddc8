"""Differentiable J0, J1, J1(x)/x against scipy.special, and their gradients."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.special as sp
import torch

from lfm_studio.engine.optics.bessel import bessel_j0, bessel_j1, bessel_j1_over_x

# Points that exercise every branch: 0, the power-series/rational switch of the J2/x
# derivative (0.5), the Cephes rational/asymptotic switch (5), and large arguments.
GRAD_POINTS = [0.0, 1e-8, -0.3, 0.49999, 0.50001, 2.0, 4.999, 5.0, 5.001, -7.5, 30.0, 150.0, 199.9]


def test_values_match_scipy_on_0_to_200():
    # Cephes rational approximations are accurate to ~2e-16 relative; |J| <= 1, so
    # 5e-15 absolute is 10x the measured 6e-16 (torch.special's own float64 versions
    # are off by up to 5e-7 here, which this test would catch).
    x = torch.linspace(0.0, 200.0, 200_001, dtype=torch.float64)
    xn = x.numpy()
    assert np.abs(bessel_j0(x).numpy() - sp.j0(xn)).max() < 5e-15
    assert np.abs(bessel_j1(x).numpy() - sp.j1(xn)).max() < 5e-15
    nonzero = xn > 0
    ratio = bessel_j1_over_x(x).numpy()
    assert np.abs(ratio[nonzero] - sp.j1(xn[nonzero]) / xn[nonzero]).max() < 5e-15
    assert ratio[0] == 0.5


def test_parity_for_negative_arguments():
    x = torch.linspace(0.0, 60.0, 6001, dtype=torch.float64)
    assert torch.equal(bessel_j0(-x), bessel_j0(x))
    assert torch.equal(bessel_j1(-x), -bessel_j1(x))
    assert torch.equal(bessel_j1_over_x(-x), bessel_j1_over_x(x))


def test_float32_input_is_evaluated_in_float64_and_rounded():
    # Only the final rounding to float32 remains: |error| <= 2^-24 since |J| <= 1.
    x = torch.linspace(0.0, 200.0, 20_001, dtype=torch.float32)
    xn = x.double().numpy()
    j0 = bessel_j0(x)
    assert j0.dtype == torch.float32
    assert np.abs(j0.double().numpy() - sp.j0(xn)).max() <= 2.0**-24
    assert np.abs(bessel_j1(x).double().numpy() - sp.j1(xn)).max() <= 2.0**-24


def test_derivatives_match_scipy():
    # d/dx of J0, J1 and J1/x against scipy's jvp; the x -> 0 limits are 0, 1/2, 0.
    x = torch.tensor([0.0, 1e-6, 0.2, 0.5, 3.0, 5.0, 17.0, 120.0], dtype=torch.float64, requires_grad=True)
    xn = x.detach().numpy()
    (g0,) = torch.autograd.grad(bessel_j0(x).sum(), x)
    (g1,) = torch.autograd.grad(bessel_j1(x).sum(), x)
    (g2,) = torch.autograd.grad(bessel_j1_over_x(x).sum(), x)
    assert np.abs(g0.numpy() - sp.jvp(0, xn)).max() < 1e-14
    assert np.abs(g1.numpy() - sp.jvp(1, xn)).max() < 1e-14
    safe = np.where(xn == 0, 1.0, xn)
    expected = np.where(xn == 0, 0.0, sp.jvp(1, xn) / safe - sp.j1(xn) / safe**2)
    # Away from 0 the reference itself loses ~1e-16/x^2 to cancellation; 1e-9 covers x = 1e-6.
    assert np.abs(g2.numpy() - expected).max() < 1e-9
    assert g1[0].item() == 0.5
    assert torch.isfinite(g2).all()


@pytest.mark.parametrize("function", [bessel_j0, bessel_j1, bessel_j1_over_x])
def test_gradcheck_float64(function):
    x = torch.tensor(GRAD_POINTS, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(function, (x,))


@pytest.mark.parametrize("function", [bessel_j0, bessel_j1])
def test_gradgradcheck_float64(function):
    x = torch.tensor(GRAD_POINTS, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradgradcheck(function, (x,))


def test_rejects_integer_and_complex_input():
    with pytest.raises(TypeError, match="floating-point"):
        bessel_j0(torch.arange(3))
    with pytest.raises(TypeError, match="floating-point"):
        bessel_j1(torch.ones(3, dtype=torch.complex64))
    with pytest.raises(TypeError, match=r"torch\.Tensor"):
        bessel_j0(1.0)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    x = torch.linspace(-50.0, 200.0, 10_001, dtype=torch.float64)
    for function in (bessel_j0, bessel_j1, bessel_j1_over_x):
        assert torch.allclose(function(x.cuda()).cpu(), function(x), rtol=0, atol=1e-14)
