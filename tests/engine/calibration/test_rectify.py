"""Rectification: closed forms, energy conservation, error against direct rendering, gradients."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.calibration import LensletLattice
from lfm_studio.engine.calibration.rectify import lenslet_block, rectify, resample_rows, unrectify
from lfm_studio.engine.calibration.synthetic import disk_pattern


def test_resample_rows_integrates_pixel_boxes():
    rows = torch.tensor([[1.0, 2.0, 3.0, 4.0]], dtype=torch.float64)
    # Bins of 1.5 px starting at -0.5 + 0.75: [-0.5, 1.0] and [1.0, 2.5] -> 1 + 2 / 2, 2 / 2 + 3.
    out = resample_rows(rows, torch.tensor([0.25], dtype=torch.float64), 1.5, 2)
    assert out[0].tolist() == pytest.approx([2.0, 4.0])
    # Bins reaching past the row count only what lies inside.
    out = resample_rows(rows, torch.tensor([3.0], dtype=torch.float64), 2.0, 2)
    assert out[0].tolist() == pytest.approx([0.5 * 3.0 + 4.0, 0.0])


def test_integer_scale_is_an_exact_block_sum():
    """Pitch 2 n px, no rotation, lenslet cells on pixel edges: each rectified pixel sums 2 x 2 pixels."""
    raw = torch.rand(120, 120, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    lattice = LensletLattice.from_geometry((30.0, 30.0), 0.0, (44.5, 44.5))
    out = rectify(raw, lattice, 15, (-1, 3, -1, 3))
    assert torch.allclose(out, raw[:90, :90].reshape(45, 2, 45, 2).sum((1, 3)), atol=1e-12)


def test_light_is_conserved_under_rotation_and_non_integer_pitch():
    shape = (300, 320)
    lattice = LensletLattice.from_geometry((15.38, 15.21), math.radians(1.7), (151.2, 158.9))
    raw = torch.zeros(shape, dtype=torch.float64)
    raw[80:220, 90:230] = torch.rand(
        140, 140, generator=torch.Generator().manual_seed(1), dtype=torch.float64
    )
    block = lenslet_block(lattice, shape)
    out = rectify(raw, lattice, 15, block)
    assert float(out.sum()) == pytest.approx(float(raw.sum()), rel=1e-12)
    assert bool((out >= -1e-12).all())


def _error(disk: bool) -> float:
    """Relative L2 difference of a rectified frame and the same scene rendered on the 15-px lattice."""
    shape, n = (330, 340), 15
    truth = LensletLattice.from_geometry((15.38, 15.38), math.radians(1.3), (166.3, 168.7))
    block = lenslet_block(truth, shape)
    i0, _, j0, _ = block
    direct_lattice = LensletLattice.from_geometry((n, n), 0.0, (-i0 * n + (n - 1) / 2, -j0 * n + (n - 1) / 2))
    if disk:
        raw = disk_pattern(shape, truth, 0.9 * 15.38)
        out = rectify(raw, truth, n, block)
        direct = disk_pattern(tuple(out.shape), direct_lattice, 0.9 * n) * truth.determinant / n**2
    else:

        def spots(size: tuple[int, int], lattice: LensletLattice, sigma: float) -> torch.Tensor:
            yy, xx = torch.meshgrid(
                torch.arange(size[0], dtype=torch.float64),
                torch.arange(size[1], dtype=torch.float64),
                indexing="ij",
            )
            points = torch.stack((yy, xx), -1)
            near = lattice.centres(lattice.lattice_coordinates(points).round())
            return torch.exp(-((points - near) ** 2).sum(-1) / (2 * sigma**2))

        raw = spots(shape, truth, 0.2 * 15.38)
        out = rectify(raw, truth, n, block)
        direct = spots(tuple(out.shape), direct_lattice, 0.2 * n) * truth.determinant / n**2
    return float((out - direct).norm() / direct.norm())


def test_error_against_direct_rendering_is_stated_and_beats_the_floor():
    """The numbers the rectify module docstring states (the all-zero answer scores 1.0)."""
    disk_error, smooth_error = _error(disk=True), _error(disk=False)
    assert disk_error < 0.1  # measured 0.082: sharp disk edges, resampled twice
    assert smooth_error < 0.02  # measured 0.014: smooth spots (sigma 0.2 pitch)
    assert smooth_error < disk_error


def test_rectify_is_differentiable_in_the_frame():
    lattice = LensletLattice.from_geometry((4.3, 4.1), math.radians(1.0), (6.2, 6.1))
    raw = torch.rand(14, 14, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: rectify(x, lattice, 3, (-1, 2, -1, 2)), (raw,))


def test_a_block_that_leaves_the_frame_is_refused():
    lattice = LensletLattice.from_geometry((15.38, 15.38), 0.0, (100.0, 100.0))
    with pytest.raises(ValueError, match=r"lenslets \(20, 20\).*do not fit.*Fix"):
        lenslet_block(lattice, (200, 200), (20, 20))
    assert lenslet_block(lattice, (200, 200), (5, 3)) == (-2, 5, -1, 3)
    with pytest.raises(ValueError, match="pixels_per_lenslet must be an odd integer"):
        rectify(torch.zeros(200, 200), lattice, 14, (-2, 5, -1, 3))


def test_unrectify_conserves_light_and_round_trips_smooth_images():
    lattice = LensletLattice.from_geometry((15.38, 15.31), math.radians(1.2), (101.3, 98.8))
    block, n, shape = (-5, 10, -5, 10), 15, (200, 200)
    yy, xx = torch.meshgrid(
        torch.arange(150.0, dtype=torch.float64), torch.arange(150.0, dtype=torch.float64), indexing="ij"
    )
    smooth = 1.0 + torch.sin(2 * math.pi * yy / 40.0) * torch.cos(2 * math.pi * xx / 55.0)
    raw = unrectify(smooth, lattice, block, shape)
    assert float(raw.sum()) == pytest.approx(float(smooth.sum()), rel=1e-12)
    back = rectify(raw, lattice, n, block)[n:-n, n:-n]  # the block's rim mixes with the dark outside
    inner = smooth[n:-n, n:-n]
    assert float((back - inner).norm() / inner.norm()) < 0.01


def test_default_block_stays_in_the_lit_field():
    """A circular field of view: the block grows only while its new outer row / column is half lit."""
    lattice = LensletLattice.from_geometry((15.0, 15.0), 0.0, (150.0, 150.0))
    lit = {(i, j) for i in range(-10, 11) for j in range(-10, 11) if i * i + j * j <= 25}
    i0, ni, j0, nj = lenslet_block(lattice, (300, 300), lit=lit)
    full = lenslet_block(lattice, (300, 300))
    assert ni * nj < full[1] * full[3]
    for row in (i0, i0 + ni - 1):
        assert 2 * sum((row, j) in lit for j in range(j0, j0 + nj)) >= nj
    for column in (j0, j0 + nj - 1):
        assert 2 * sum((i, column) in lit for i in range(i0, i0 + ni)) >= ni
    assert i0 <= -3 and i0 + ni - 1 >= 3 and j0 <= -3 and j0 + nj - 1 >= 3  # the 7 x 7 core is lit
