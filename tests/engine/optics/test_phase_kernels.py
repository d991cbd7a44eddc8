"""Shared phase kernels: closed forms, float/tensor arguments, gradients; PhaseMask sampling."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.phase_kernels import (
    aperture_coverage,
    fresnel_chirp,
    lens_phase,
    shift_ramp,
    unit_phasor,
    wavenumber,
)
from lfm_studio.engine.optics.phase_mask import PhaseMask
from lfm_studio.engine.optics.pupils import disk_coverage, radial_distance, square_coverage

F64 = torch.float64
X = torch.tensor([[-3e-6, 0.0, 2e-6]], dtype=F64)
Y = torch.tensor([[1e-6], [-4e-6]], dtype=F64)


def test_closed_forms_at_a_point():
    k = wavenumber(0.5e-6)
    assert k == pytest.approx(2 * math.pi / 0.5e-6, rel=1e-15)
    x, y = torch.tensor(3e-6, dtype=F64), torch.tensor(-4e-6, dtype=F64)  # r = 5 um
    assert float(lens_phase(x, y, 2e-3, k)) == pytest.approx(-k * 25e-12 / 4e-3, rel=1e-14)
    assert float(lens_phase(x, y, 2e-3, k, center=(3e-6, 0.0))) == pytest.approx(
        -k * 16e-12 / 4e-3, rel=1e-14
    )
    assert float(fresnel_chirp(x, y, 5e-3, k)) == pytest.approx(k * 25e-12 / 10e-3, rel=1e-14)
    assert float(shift_ramp(x, y, (1e-6, 2e-6), k, 5e-3)) == pytest.approx(
        -k * (3e-12 - 8e-12) / 5e-3, rel=1e-14
    )
    # An in-focus camera (d = f): lens and Fresnel chirps cancel.
    assert float(lens_phase(x, y, 5e-3, k) + fresnel_chirp(x, y, 5e-3, k)) == pytest.approx(0.0, abs=1e-12)
    assert torch.allclose(
        unit_phasor(torch.tensor([math.pi / 2], dtype=F64), torch.complex64), torch.tensor([1j])
    )


def test_shift_ramp_moves_a_dft_output_by_the_shift():
    # Single-FFT Fresnel transform: output spacing lambda d / (N dx). A shift of 2.5 output
    # samples through the ramp equals the DFT of the field evaluated 2.5 samples further.
    n, dx, wavelength, d = 64, 2e-6, 0.5e-6, 1e-3
    k, step = wavenumber(wavelength), wavelength * d / (n * dx)
    x = (torch.arange(n, dtype=F64) - n // 2) * dx
    field = torch.exp(-((x / (8 * dx)) ** 2)).to(torch.complex128)
    shifted = torch.fft.fft(
        field * unit_phasor(shift_ramp(x, 0.0, (2.5 * step, 0.0), k, d), torch.complex128)
    )
    u = torch.arange(n, dtype=F64) + 2.5  # output index + shift, direct DFT sum
    direct = (
        field[None, :] * torch.exp(-2j * math.pi * u[:, None] * torch.arange(n, dtype=F64)[None, :] / n)
    ).sum(1) * torch.exp(torch.tensor(2j * math.pi * 2.5 * (n // 2) / n))  # the ramp is zero at x = 0
    assert torch.allclose(shifted, direct, atol=1e-10 * float(direct.abs().max()))


def test_float_and_tensor_arguments_agree_and_keep_the_graph():
    f = torch.tensor(2e-3, dtype=F64, requires_grad=True)
    k = wavenumber(0.5e-6)
    as_tensor = lens_phase(X, Y, f, k)
    assert torch.allclose(as_tensor, lens_phase(X, Y, 2e-3, k), rtol=1e-15, atol=0)
    as_tensor.sum().backward()
    # d/df of -k r^2 / (2 f) = k r^2 / (2 f^2)
    expected = float((k * (X**2 + Y**2) / (2 * 2e-3**2)).sum())
    assert float(f.grad) == pytest.approx(expected, rel=1e-12)


def test_aperture_coverage_dispatches_and_names_bad_shapes():
    spacing = (1e-6, 1e-6)
    assert torch.equal(aperture_coverage("circle", X, Y, 6e-6, spacing, antialias=True),
                       disk_coverage(X, Y, 3e-6, spacing, antialias=True))  # fmt: skip
    assert torch.equal(aperture_coverage("square", X, Y, 6e-6, spacing, antialias=False),
                       square_coverage(X, Y, 6e-6, spacing, antialias=False))  # fmt: skip
    with pytest.raises(ValueError, match=r"aperture shape must be one of .*got 'hexagon'"):
        aperture_coverage("hexagon", X, Y, 6e-6, spacing, antialias=True)


def test_radial_distance_has_a_zero_gradient_at_the_axis():
    x = torch.tensor([0.0, 3.0], dtype=F64, requires_grad=True)
    y = torch.tensor([0.0, 4.0], dtype=F64, requires_grad=True)
    r = radial_distance(x, y)
    assert r.tolist() == [0.0, 5.0]
    r.sum().backward()
    assert x.grad.tolist() == [0.0, pytest.approx(0.6)] and y.grad.tolist() == [0.0, pytest.approx(0.8)]


def test_phase_mask_sample_is_exact_at_centres_bilinear_between_and_differentiable():
    grid = Grid((4, 5), (2e-6, 1e-6))
    phase = torch.arange(20, dtype=F64).reshape(4, 5)
    mask = PhaseMask(grid, phase, trainable=True)
    y, x = grid.axes()
    assert torch.allclose(mask.sample(x[None, :], y[:, None]), phase, atol=1e-12)
    # Half-way between samples (row 1, cols 2-3) and (rows 1-2, col 2): the means.
    with torch.no_grad():
        assert float(mask.sample(torch.tensor(0.5e-6), torch.tensor(-2e-6))) == pytest.approx(7.5)
        assert float(mask.sample(torch.tensor(0.0), torch.tensor(-1e-6))) == pytest.approx(9.5)
    mask.sample(torch.tensor(0.5e-6), torch.tensor(-2e-6)).backward()
    assert mask.phase.grad[1, 2] == pytest.approx(0.5) and mask.phase.grad[1, 3] == pytest.approx(0.5)
    assert float(mask.phase.grad.sum()) == pytest.approx(1.0)
