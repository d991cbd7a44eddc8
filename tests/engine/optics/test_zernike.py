"""Noll Zernike polynomials: the index table, closed forms, orthonormality on the unit disk, gradients."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.optics.zernike import is_rotationally_symmetric, noll_to_nm, zernike, zernike_phase

F64 = torch.float64


def test_noll_table():
    expected = [(0, 0), (1, 1), (1, 1), (2, 0), (2, 2), (2, 2), (3, 1), (3, 1), (3, 3), (3, 3), (4, 0), (4, 2),
                (4, 2), (4, 4), (4, 4), (5, 1), (5, 1), (5, 3), (5, 3), (5, 5), (5, 5), (6, 0)]  # fmt: skip
    assert [noll_to_nm(j) for j in range(1, 23)] == expected
    assert [j for j in range(1, 38) if is_rotationally_symmetric(j)] == [1, 4, 11, 22, 37]
    for bad in (0, -1, 2.0, True):
        with pytest.raises(ValueError, match="Noll index must be an integer >= 1"):
            noll_to_nm(bad)


def test_closed_forms_of_the_first_terms():
    """Noll's table (J. Opt. Soc. Am. 66, 207, 1976), in polar form, at random points."""
    gen = torch.Generator().manual_seed(0)
    r = torch.rand(50, generator=gen, dtype=F64)
    t = 2 * math.pi * torch.rand(50, generator=gen, dtype=F64)
    x, y = r * torch.cos(t), r * torch.sin(t)
    s3, s5, s6, s8 = math.sqrt(3), math.sqrt(5), math.sqrt(6), math.sqrt(8)
    forms = {
        1: torch.ones_like(r),
        2: 2 * r * torch.cos(t),
        3: 2 * r * torch.sin(t),
        4: s3 * (2 * r**2 - 1),
        5: s6 * r**2 * torch.sin(2 * t),
        6: s6 * r**2 * torch.cos(2 * t),
        7: s8 * (3 * r**3 - 2 * r) * torch.sin(t),
        8: s8 * (3 * r**3 - 2 * r) * torch.cos(t),
        9: s8 * r**3 * torch.sin(3 * t),
        10: s8 * r**3 * torch.cos(3 * t),
        11: s5 * (6 * r**4 - 6 * r**2 + 1),
        12: math.sqrt(10) * (4 * r**4 - 3 * r**2) * torch.cos(2 * t),
        13: math.sqrt(10) * (4 * r**4 - 3 * r**2) * torch.sin(2 * t),
    }
    for j, form in forms.items():
        assert torch.allclose(zernike(j, x, y), form, rtol=0, atol=1e-12), j


def test_orthonormal_on_a_fine_disk_grid():
    """(1/pi) integral over the unit disk of Z_i Z_j = delta_ij for j = 1..28 (orders 0-6), on a
    polar midpoint grid of 600 radii x 720 angles (the polynomials are of degree <= 12)."""
    nr, nt = 600, 720
    r = (torch.arange(nr, dtype=F64) + 0.5) / nr
    t = (torch.arange(nt, dtype=F64) + 0.5) * 2 * math.pi / nt
    x, y = r[:, None] * torch.cos(t)[None, :], r[:, None] * torch.sin(t)[None, :]
    weight = (r[:, None] / nr) * (2 * math.pi / nt) / math.pi  # r dr dtheta / pi
    terms = torch.stack([zernike(j, x, y) for j in range(1, 29)])
    gram = torch.einsum("iab,jab,ab->ij", terms, terms, weight.expand_as(x))
    assert float((gram - torch.eye(28, dtype=F64)).abs().max()) < 1e-3


def test_phase_sums_terms_in_waves_and_is_differentiable():
    x = torch.linspace(-2.0, 2.0, 9, dtype=F64)[None, :]
    y = torch.linspace(-2.0, 2.0, 9, dtype=F64)[:, None]
    c4 = torch.tensor(0.1, dtype=F64, requires_grad=True)
    phase = zernike_phase({4: c4, 2: -0.05}, x, y, 2.0)
    expected = 2 * math.pi * (0.1 * zernike(4, x / 2, y / 2) - 0.05 * zernike(2, x / 2, y / 2))
    assert torch.allclose(phase, expected, atol=1e-12)
    phase.sum().backward()
    assert float(c4.grad) == pytest.approx(float(2 * math.pi * zernike(4, x / 2, y / 2).sum()), rel=1e-12)
    assert float(zernike_phase({}, x, y, 2.0).abs().max()) == 0.0
    with pytest.raises(ValueError, match="zernike_waves: Noll indices must be integers >= 1; got 0"):
        zernike_phase({0: 0.1}, x, y, 2.0)
