"""Adjointness and non-negativity of both projectors over random shapes and random kernels.

``<A x, y> = <x, A^T y>`` for random ``x``, ``y`` in float64: both sides are sums of the same
products rounded differently, so they agree to ~1e-16 times ``|A x| |y|`` per FFT pass; bound
1e-12. Non-negative PSFs and volumes give non-negative images up to FFT rounding (16 eps of the
largest value, the engine's own rounding floor).
"""

from __future__ import annotations

import torch
from hypothesis import given
from hypothesis import strategies as st

from lfm_studio.engine.operators import ShiftInvariantProjector
from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector
from tests.stress.levels import examples


def _check_adjoint(projector, seed: int) -> None:
    gen = torch.Generator().manual_seed(seed)
    x = torch.rand(projector.volume_shape, generator=gen, dtype=torch.float64)
    y = torch.rand(projector.image_shape, generator=gen, dtype=torch.float64)
    ax, aty = projector.forward(x), projector.adjoint(y)
    assert tuple(ax.shape) == tuple(projector.image_shape)
    assert tuple(aty.shape) == tuple(projector.volume_shape)
    lhs, rhs = float((ax * y).sum()), float((x * aty).sum())
    assert abs(lhs - rhs) <= 1e-12 * float(ax.norm() * y.norm())
    eps = torch.finfo(torch.float64).eps
    assert float(ax.min()) >= -16 * eps * float(ax.abs().max())
    assert float(aty.min()) >= -16 * eps * float(aty.abs().max())


@examples(ci=25, full=1000)
@given(
    depths=st.integers(1, 4),
    psf=st.tuples(st.integers(1, 70), st.integers(1, 70)),
    lateral=st.tuples(st.integers(1, 70), st.integers(1, 70)),
    chunk=st.one_of(st.none(), st.integers(1, 4)),
    seed=st.integers(0, 2**31 - 1),
)
def test_shift_invariant_projector_is_adjoint_for_any_shape(depths, psf, lateral, chunk, seed):
    gen = torch.Generator().manual_seed(seed)
    kernel = torch.rand((depths, *psf), generator=gen, dtype=torch.float64)
    _check_adjoint(ShiftInvariantProjector(kernel, lateral, depth_chunk=chunk), seed + 1)


@st.composite
def lattice_projectors(draw: st.DrawFn) -> LensletLatticeProjector:
    """Random patterns grouped by reach: ``(Zg, S, S, (2R + 1) Q, (2R + 1) Q)`` per group."""
    depths = draw(st.integers(1, 4))
    s = draw(st.sampled_from((1, 3, 5)))
    q = draw(st.integers(1, 7))
    lenslets = (draw(st.integers(1, 6)), draw(st.integers(1, 6)))
    reaches = draw(st.lists(st.integers(0, 2), min_size=depths, max_size=depths))
    gen = torch.Generator().manual_seed(draw(st.integers(0, 2**31 - 1)))
    groups = []
    for reach in sorted(set(reaches)):
        indices = [i for i, r in enumerate(reaches) if r == reach]
        h = (2 * reach + 1) * q
        groups.append((indices, torch.rand((len(indices), s, s, h, h), generator=gen, dtype=torch.float64)))
    return LensletLatticeProjector(groups, depths, lenslets, q)


@examples(ci=25, full=1000)
@given(lattice_projectors(), st.integers(0, 2**31 - 1))
def test_lenslet_lattice_projector_is_adjoint_for_any_lattice(projector, seed):
    _check_adjoint(projector, seed)
