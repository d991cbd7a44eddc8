"""Pupils: binary and antialiased circular/square masks, apply_pupil, errors, gradients."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.pupils import apply_pupil, circular_pupil, square_pupil
from lfm_studio.engine.optics.sources import plane_wave
from lfm_studio.engine.units import nm, um

WAVELENGTH = 500 * nm


def _supersampled_disk(grid: Grid, radius: float, center: tuple[float, float], n: int = 64) -> torch.Tensor:
    """Reference coverage: fraction of n x n sub-pixel centres inside the disk."""
    y, x = grid.axes()
    o = (torch.arange(n, dtype=torch.float64) + 0.5) / n - 0.5
    xs = x[None, :, None, None] + o[None, None, None, :] * grid.dx - center[0]
    ys = y[:, None, None, None] + o[None, None, :, None] * grid.dy - center[1]
    return ((xs**2 + ys**2) <= radius**2).double().mean(dim=(-1, -2))


@pytest.mark.parametrize(
    ("radius_px", "center_px"), [(5.1, (0.37, -0.21)), (7.3, (0.0, 0.0)), (9.0, (0.5, 0.5))]
)
def test_antialiased_disk_matches_area_and_supersampling(radius_px, center_px):
    grid = Grid(24, 1 * um)
    radius, center = radius_px * um, (center_px[0] * um, center_px[1] * um)
    mask = circular_pupil(grid, 2 * radius, center=center, antialias=True)
    assert mask.dtype == torch.float64 and mask.shape == (24, 24)
    assert float(mask.min()) >= 0.0 and float(mask.max()) <= 1.0
    # Total area: the tangent-edge coverage with the sagitta correction leaves a curvature
    # error of a few 1e-5 (measured 1.1e-5, 2.1e-5, -3.6e-5 here; binary masks and the
    # uncorrected tangent edge: ~3e-3 and ~4e-4). Tolerance 1e-4.
    area = float(mask.sum()) * grid.pixel_area
    assert area == pytest.approx(math.pi * radius**2, rel=1e-4)
    # Per pixel vs 64 x 64 supersampling (its own error ~1e-3): measured 8e-3 at R = 5.1 px.
    reference = _supersampled_disk(grid, radius, center)
    assert float((mask - reference).abs().max()) < 1.5e-2


def test_binary_disk_counts_pixel_centres_and_keeps_the_rim():
    grid = Grid(16, 2 * um)
    mask = circular_pupil(grid, 12 * um)  # R = 3 pixels exactly: (3, 0) lies on the rim
    y, x = grid.axes()
    expected = ((x[None, :] / (2 * um)) ** 2 + (y[:, None] / (2 * um)) ** 2 <= 9.0 + 1e-9).double()
    assert torch.equal(mask, expected)
    assert int(mask.sum()) == 29  # lattice points with i^2 + j^2 <= 9
    assert mask[8, 11] == 1.0 and mask[8, 12] == 0.0


def test_square_pupil_exact_area_and_binary_count():
    grid = Grid((20, 30), (1 * um, 0.7 * um))
    mask = square_pupil(grid, 6.3 * um, center=(0.41 * um, -1.13 * um), antialias=True)
    # Antialiased square coverage is the exact interval overlap: area to rounding.
    assert float(mask.sum()) * grid.pixel_area == pytest.approx((6.3 * um) ** 2, rel=1e-12)
    binary = square_pupil(Grid(16, 1 * um), 4 * um)  # edges at +-2 px: 5 x 5 centres
    assert int(binary.sum()) == 25


def test_apply_pupil_broadcasts_and_keeps_dtype():
    grid = Grid(16, 1 * um)
    data = torch.randn((3, 16, 16), dtype=torch.complex64, generator=torch.Generator().manual_seed(1))
    field = Field(data, grid, WAVELENGTH)
    mask = circular_pupil(grid, 9 * um, antialias=True)
    out = apply_pupil(field, mask)
    assert out.dtype == torch.complex64 and out.grid == grid
    torch.testing.assert_close(out.data, data * mask.float(), rtol=0, atol=0)
    phase_plate = torch.polar(mask, mask)  # complex masks pass as they are
    torch.testing.assert_close(apply_pupil(field, phase_plate).data, data * phase_plate.to(torch.complex64))


def test_named_errors():
    grid = Grid(16, 1 * um)
    field = plane_wave(grid, WAVELENGTH)
    with pytest.raises(ValueError, match=r"diameter must be a finite number > 0 m; got 0 m"):
        circular_pupil(grid, 0.0)
    with pytest.raises(ValueError, match=r"width must be a finite number > 0 m; got -1e-06 m"):
        square_pupil(grid, -1 * um)
    with pytest.raises(ValueError, match="diameter"):
        circular_pupil(grid, float("nan"))
    with pytest.raises(ValueError, match="center x must be finite"):
        circular_pupil(grid, 4 * um, center=(float("inf"), 0.0))
    with pytest.raises(
        ValueError, match=r"mask shape \(8, 8\) does not end in the field's grid shape \(16, 16\)"
    ):
        apply_pupil(field, torch.ones(8, 8))
    bad = torch.ones(16, 16)
    bad[3, 4] = float("nan")
    with pytest.raises(ValueError, match="mask contains 1 NaN/Inf"):
        apply_pupil(field, bad)
    with pytest.raises(TypeError, match=r"mask must be a torch\.Tensor"):
        apply_pupil(field, 1.0)


def test_gradcheck_pupil_application_and_antialiased_diameter():
    grid = Grid(16, 1 * um)
    gen = torch.Generator().manual_seed(2)
    data = torch.randn((16, 16), dtype=torch.complex128, generator=gen, requires_grad=True)
    mask = torch.rand((16, 16), dtype=torch.float64, generator=gen, requires_grad=True)

    def apply(data, mask):
        return apply_pupil(Field(data, grid, WAVELENGTH), mask).data

    assert torch.autograd.gradcheck(apply, (data, mask), fast_mode=True)

    # Diameter in micrometres (a dimensionless input keeps finite differences well scaled);
    # centre off-pixel so that no edge pixel sits on a kink of the piecewise coverage.
    def pupil(d_um):
        return circular_pupil(grid, d_um * um, center=(0.3 * um, -0.2 * um), antialias=True)

    diameter = torch.tensor(9.7, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(pupil, (diameter,))
    # The gradient is the rim length in pixels / 2 (d area / d D = pi D / 2 = perimeter / 2).
    (grad,) = torch.autograd.grad(pupil(diameter).sum(), diameter)
    assert float(grad) == pytest.approx(math.pi * 9.7 / 2, rel=1e-2)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    grid = Grid(32, 1 * um)
    cpu = circular_pupil(grid, 11 * um, center=(0.3 * um, 0.1 * um), antialias=True)
    gpu = circular_pupil(grid, 11 * um, center=(0.3 * um, 0.1 * um), antialias=True, device="cuda")
    assert gpu.device.type == "cuda"
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=0, atol=1e-12)
    field = plane_wave(grid, WAVELENGTH)
    torch.testing.assert_close(apply_pupil(field.to("cuda"), gpu).data.cpu(), apply_pupil(field, cpu).data)
