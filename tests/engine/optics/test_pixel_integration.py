"""Pixel integration of a sampled intensity against the analytic box integral of a Gaussian spot."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.optics.pixel_integration import integrate_pixels


def _gaussian_pixels(n_pixels: int, factor: int, sigma: float, centre: tuple[float, float]):
    """Sub-samples (intensity x sub-sample area) of a unit-power Gaussian on ``n_pixels`` unit
    pixels, and its exact power per pixel (products of erf differences), float64."""
    h = 1.0 / factor
    sub = (torch.arange(n_pixels * factor, dtype=torch.float64) + 0.5) * h  # sub-sample centres
    gy = torch.exp(-((sub - centre[0]) ** 2) / (2 * sigma**2)) / (math.sqrt(2 * math.pi) * sigma)
    gx = torch.exp(-((sub - centre[1]) ** 2) / (2 * sigma**2)) / (math.sqrt(2 * math.pi) * sigma)
    samples = gy[:, None] * gx[None, :] * h * h
    edges = torch.arange(n_pixels + 1, dtype=torch.float64)

    def cdf(x, c):
        return 0.5 * (1 + torch.erf((x - c) / (math.sqrt(2) * sigma)))

    py = cdf(edges[1:], centre[0]) - cdf(edges[:-1], centre[0])
    px = cdf(edges[1:], centre[1]) - cdf(edges[:-1], centre[1])
    return samples, py[:, None] * px[None, :]


@pytest.mark.parametrize("factor", [1, 2, 3, 4])
def test_fourier_integration_is_exact_for_a_well_sampled_spot(factor):
    # sigma = 2 pixels: the spectrum exp(-2 pi^2 sigma^2 f^2) is 3e-9 at f = 0.5 per pixel, so
    # even one sample per pixel is alias-free, while the midpoint rule is off by ~1/(24 s^2 sigma^2).
    samples, exact = _gaussian_pixels(32, factor, 2.0, (15.3, 16.7))
    fourier = integrate_pixels(samples, factor, "fourier")
    midpoint = integrate_pixels(samples, factor, "midpoint")
    error = float((fourier - exact).norm() / exact.norm())
    midpoint_error = float((midpoint - exact).norm() / exact.norm())
    assert error < 1e-9, error
    assert midpoint_error > 1e-3 / factor**2  # the midpoint rule's 1/s^2 error is real
    assert float(fourier.sum()) == pytest.approx(1.0, abs=1e-9)


def test_fourier_integration_of_an_undersampled_spot_is_off_but_non_negative():
    # sigma = 0.3 pixels at one sample per pixel aliases: the result is not exact, never negative,
    # and 8 sub-samples per pixel (spectrum 1e-12 at their Nyquist frequency) bring it back.
    coarse, exact = _gaussian_pixels(16, 1, 0.3, (7.6, 8.2))
    fine, _ = _gaussian_pixels(16, 8, 0.3, (7.6, 8.2))
    aliased = integrate_pixels(coarse, 1, "fourier")
    assert float(aliased.min()) >= 0.0
    assert float((aliased - exact).norm() / exact.norm()) > 1e-2
    assert float((integrate_pixels(fine, 8, "fourier") - exact).norm() / exact.norm()) < 1e-9


def test_float32_batches_and_bad_arguments():
    samples, exact = _gaussian_pixels(16, 2, 1.0, (8.0, 8.0))
    batch = torch.stack([samples, 2 * samples]).float()
    out = integrate_pixels(batch, 2, "fourier")
    assert out.dtype == torch.float32 and out.shape == (2, 16, 16)
    assert torch.allclose(out[1], 2 * exact.float(), atol=1e-6)
    with pytest.raises(ValueError, match="pixel_integration must be one of"):
        integrate_pixels(samples, 2, "simpson")
    with pytest.raises(ValueError, match="not a multiple of 3"):
        integrate_pixels(samples, 3, "fourier")


@pytest.mark.parametrize(
    ("shape", "factor"),
    [
        ((2, 12, 18), 3),
        ((20, 16), 2),
        ((7, 9), 1),
        ((3, 25, 30), 5),
        ((24, 24), 4),
        ((15, 21), 3),
        ((10, 35), 5),
    ],
)
def test_fourier_integration_equals_the_two_dimensional_box_filter_read_at_the_centres(shape, factor):
    # The folded per-axis evaluation against the plain one: the 2-D product of sinc(f p) and the
    # centring shift on the sub-sample spectrum, a full inverse, every factor-th sample (odd and even sizes).
    torch.manual_seed(0)
    power = torch.rand(shape, dtype=torch.float64)
    ny, nx = shape[-2:]
    fy = torch.fft.fftfreq(ny, d=1.0 / factor, dtype=torch.float64)
    fx = torch.fft.fftfreq(nx, d=1.0 / factor, dtype=torch.float64)
    shift = (factor - 1) / (2.0 * factor)
    ty = factor * torch.sinc(fy) * torch.exp(2j * math.pi * fy * shift)
    tx = factor * torch.sinc(fx) * torch.exp(2j * math.pi * fx * shift)
    filtered = torch.fft.ifft2(torch.fft.fft2(power) * ty[:, None] * tx[None, :]).real
    expected = filtered[..., ::factor, ::factor].clamp_min(0.0)
    got = integrate_pixels(power, factor, "fourier")
    assert got.shape == expected.shape
    assert torch.allclose(got, expected, rtol=0, atol=1e-13 * float(expected.abs().max()))


@pytest.mark.parametrize("method", ["fourier", "midpoint"])
def test_a_transposed_layout_gives_the_same_pixels(method):
    # Lenslet fields leave their power in a transposed memory layout (column transforms on a
    # transposed copy); the integration then runs on the contiguous tensor and transposes back.
    torch.manual_seed(1)
    power = torch.rand(2, 18, 12, dtype=torch.float64)
    transposed = power.mT.contiguous().mT  # same values, column-major in the last two dims
    assert not transposed.is_contiguous() and transposed.mT.is_contiguous()
    got = integrate_pixels(transposed, 3, method)
    expected = integrate_pixels(power, 3, method)
    assert got.shape == (2, 6, 4)
    assert torch.allclose(got, expected, rtol=1e-13, atol=1e-15)


def test_fourier_integration_gradient_matches_finite_differences():
    # The fold adds slices in place into a copy of the half spectrum: autograd must see through it.
    torch.manual_seed(2)
    power = torch.rand(1, 9, 15, dtype=torch.float64, requires_grad=True)
    weights = torch.rand(1, 3, 5, dtype=torch.float64)

    def objective(x):
        return (torch.fft.fft(integrate_pixels(x, 3, "fourier"), dim=-1).abs() * weights).sum()

    assert torch.autograd.gradcheck(objective, (power,))
