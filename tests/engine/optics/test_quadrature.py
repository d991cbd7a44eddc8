"""Gauss-Legendre nodes and weights."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lfm_studio.engine.optics.quadrature import _legendre_rule, gauss_legendre


@pytest.mark.parametrize("n", [1, 2, 5, 64, 257])
def test_matches_numpy_leggauss(n):
    # numpy's leggauss weights carry ~1e-14 of their own error at n ~ 250 (eigenvalues
    # plus one Newton step; ours are checked independently by the moment test below).
    x, w = gauss_legendre(n)
    xr, wr = np.polynomial.legendre.leggauss(n)
    assert x.dtype == torch.float64
    assert np.abs(x.numpy() - xr).max() < 1e-14
    assert np.abs(w.numpy() - wr).max() < 1e-13


@pytest.mark.parametrize("n", [3, 20, 1000])
def test_polynomials_of_degree_2n_minus_1_are_exact(n):
    # integral_0^1 t^p dt = 1/(p+1) for p = 2n-1; round-off grows like n eps (3e-14 at n = 1000).
    t, w = gauss_legendre(n, 0.0, 1.0)
    p = 2 * n - 1
    assert math.isclose(float((w * t**p).sum()) * (p + 1), 1.0, rel_tol=1e-12)


def test_degree_2n_is_not_exact():
    # The test above can fail: with n = 3, t^6 is integrated with a relative error of 2.5e-3.
    t, w = gauss_legendre(3, 0.0, 1.0)
    assert abs(float((w * t**6).sum()) * 7 - 1.0) > 1e-3


def test_oscillatory_integral_converges():
    # integral_-1^1 cos(50 t) dt = 2 sin(50) / 50; 64 nodes resolve 50 rad of phase.
    t, w = gauss_legendre(64)
    assert abs(float((w * torch.cos(50 * t)).sum()) - 2 * math.sin(50) / 50) < 1e-14


def test_differentiable_in_the_interval():
    # d/db integral_a^b exp(t) dt = exp(b), d/da = -exp(a).
    def integral(a, b):
        t, w = gauss_legendre(16, a, b)
        return (w * torch.exp(t)).sum()

    a = torch.tensor(-0.3, dtype=torch.float64, requires_grad=True)
    b = torch.tensor(1.1, dtype=torch.float64, requires_grad=True)
    ga, gb = torch.autograd.grad(integral(a, b), (a, b))
    assert math.isclose(float(gb), math.exp(1.1), rel_tol=1e-13)
    assert math.isclose(float(ga), -math.exp(-0.3), rel_tol=1e-13)
    assert torch.autograd.gradcheck(integral, (a, b))


def test_rule_is_cached():
    assert _legendre_rule(33)[0] is _legendre_rule(33)[0]


@pytest.mark.parametrize("n", [0, -3, 2.5, True])
def test_bad_order(n):
    with pytest.raises(ValueError, match="Gauss-Legendre nodes"):
        gauss_legendre(n)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    x, w = gauss_legendre(50, 0.0, 2.0, device="cuda")
    xc, wc = gauss_legendre(50, 0.0, 2.0)
    assert x.device.type == "cuda"
    assert torch.allclose(x.cpu(), xc, rtol=0, atol=1e-15) and torch.allclose(w.cpu(), wc, rtol=0, atol=1e-15)
