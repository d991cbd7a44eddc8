"""Wiener (eq. 4.5) limits and formula; multi-depth Tikhonov against dense least-squares solves."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lfm_studio.engine.operators import ShiftInvariantProjector
from lfm_studio.engine.reconstruct import tikhonov, wiener
from lfm_studio.engine.reconstruct.fourier_geometry import centre_offsets


def _random(shape, seed):
    return torch.rand(shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def _well_conditioned_psf(depths: int, size: int = 24, seed: int = 0) -> torch.Tensor:
    """A centred delta plus a 5 x 5 positive blur of total 0.5: |OTF| >= 0.5 at every frequency."""
    psf = torch.zeros((depths, size, size), dtype=torch.float64)
    c = size // 2
    blur = _random((depths, 5, 5), seed)
    psf[:, c - 2 : c + 3, c - 2 : c + 3] = 0.5 * blur / blur.sum(dim=(1, 2), keepdim=True)
    psf[:, c, c] += 1.0
    return psf


def test_wiener_at_infinite_snr_inverts_each_depth_exactly():
    # The 6 x 6 volume convolved with a PSF supported on the central 5 x 5 stays inside the 24 x 24
    # sensor, so the embedded image is the whole linear convolution and Y / H is exact.
    projector = ShiftInvariantProjector(_well_conditioned_psf(2), (6, 6))
    volume = _random((2, 6, 6), 1)
    for depth in range(2):
        only = torch.zeros_like(volume)
        only[depth] = volume[depth]
        result = wiener(projector, projector.forward(only), snr=math.inf)
        # |H| >= 0.5: float64 rounding of a few FFTs, ~1e-15 relative.
        assert torch.allclose(result[depth], volume[depth], rtol=0, atol=1e-12)
    finite = wiener(projector, projector.forward(volume), snr=1e12)
    exact = wiener(projector, projector.forward(volume), snr=math.inf)
    # Finite SNR differs by |H|^-2 M^2 / SNR <= 4 * 2.25 / 1e12 relative: 1e-10 bound.
    assert torch.allclose(finite, exact, rtol=0, atol=1e-10 * float(exact.abs().max()))


def test_wiener_at_vanishing_snr_gives_zero():
    projector = ShiftInvariantProjector(_well_conditioned_psf(2), (6, 6))
    image = projector.forward(_random((2, 6, 6), 2))
    scale = float(wiener(projector, image, snr=math.inf).abs().max())
    # The gain is SNR |H| / M^2 for SNR -> 0: 1e-12 * (1.5 / 1.5^2) ~ 1e-12 relative.
    assert float(wiener(projector, image, snr=1e-12).abs().max()) < 1e-11 * scale


def test_wiener_matches_equation_4_5_written_with_numpy():
    psf = _random((3, 12, 10), 3)
    projector = ShiftInvariantProjector(psf, (5, 4))
    image = _random((12, 10), 4)
    snr = 7.0
    fy, fx = projector.fft_shape
    oy, ox = centre_offsets(projector)
    padded = np.zeros((3, fy, fx))
    padded[:, :12, :10] = psf.numpy()
    embedded = np.zeros((fy, fx))
    embedded[oy : oy + 12, ox : ox + 10] = image.numpy()
    h = np.fft.rfft2(padded)
    m = np.abs(h).reshape(3, -1).max(axis=1)[:, None, None]
    # eq. 4.5 with the OTF normalised to its peak M (our SNR convention): (1/(1 + 1/(|h|^2 SNR))) Y / h / M.
    hn = h / m
    spectrum = (1.0 / (1.0 + 1.0 / (np.abs(hn) ** 2 * snr))) * np.fft.rfft2(embedded) / hn / m
    expected = np.fft.irfft2(spectrum, s=(fy, fx))[:, :5, :4]
    assert np.allclose(wiener(projector, image, snr=snr).numpy(), expected, rtol=0, atol=1e-12)


def _circular_operator(projector) -> np.ndarray:
    """Dense periodic convolution on the FFT window: (Fy Fx) x (Z Fy Fx), column by column."""
    z = projector.volume_shape[0]
    fy, fx = projector.fft_shape
    otf = projector.otf.numpy()
    columns = []
    for index in range(z * fy * fx):
        unit = np.zeros((z, fy, fx))
        unit.flat[index] = 1.0
        columns.append(np.fft.irfft2((np.fft.rfft2(unit) * otf).sum(axis=0), s=(fy, fx)).ravel())
    return np.stack(columns, axis=1)


def _embedded(projector, image: torch.Tensor) -> np.ndarray:
    out = np.zeros(projector.fft_shape)
    oy, ox = centre_offsets(projector)
    out[oy : oy + image.shape[0], ox : ox + image.shape[1]] = image.numpy()
    return out.ravel()


@pytest.fixture(scope="module")
def tiny():
    projector = ShiftInvariantProjector(_random((3, 6, 5), 5), (4, 3))  # FFT window 9 x 8
    image = projector.forward(_random((3, 4, 3), 6)) + 0.05 * _random((6, 5), 7)
    return projector, image


@pytest.mark.parametrize("mu", [1e-2, 0.0])
def test_tikhonov_closed_form_equals_a_dense_solve_of_the_window_model(tiny, mu):
    projector, image = tiny
    c = _circular_operator(projector)  # 72 x 216: underdetermined, one equation per frequency
    e = _embedded(projector, image)
    z, (fy, fx), (_, vy, vx) = projector.volume_shape[0], projector.fft_shape, projector.volume_shape
    if mu:
        mu_abs = mu * float((projector.otf.abs() ** 2).sum(0).max())
        full = np.linalg.solve(c.T @ c + mu_abs * np.eye(c.shape[1]), c.T @ e)
    else:
        full = np.linalg.pinv(c) @ e  # minimum-norm least squares
    expected = full.reshape(z, fy, fx)[:, :vy, :vx]
    # Dense solve and pinv of a 72 x 216 float64 system: ~1e-13 relative; bound 1e-10.
    result = tikhonov(projector, image, mu=mu).numpy()
    assert np.allclose(result, expected, rtol=0, atol=1e-10 * np.abs(expected).max())


def test_tikhonov_refined_equals_the_dense_solve_of_the_projector(tiny):
    projector, image = tiny
    n = int(np.prod(projector.volume_shape))
    units = torch.eye(n, dtype=torch.float64).reshape(n, *projector.volume_shape)
    a = np.stack(
        [projector.forward(unit).numpy().ravel() for unit in units], axis=1
    )  # dense A, column by column
    mu = 1e-2
    mu_abs = mu * float((projector.otf.abs() ** 2).sum(0).max())
    expected = np.linalg.solve(a.T @ a + mu_abs * np.eye(n), a.T @ image.numpy().ravel()).reshape(
        projector.volume_shape
    )
    closed = tikhonov(projector, image, mu=mu).numpy()
    refined = tikhonov(projector, image, mu=mu, refine=60).numpy()
    scale = np.abs(expected).max()
    assert np.abs(closed - expected).max() > 1e-3 * scale  # the window model is not the projector's
    # Preconditioned CG on a 36-unknown SPD system converges to rounding well within 60 steps.
    assert np.allclose(refined, expected, rtol=0, atol=1e-9 * scale)


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda p, y: wiener(p, y, snr=0.0), "snr must be > 0"),
        (lambda p, y: wiener(p, y, snr=float("nan")), "snr must be > 0"),
        (lambda p, y: tikhonov(p, y, mu=-1.0), "mu must be finite and >= 0"),
        (lambda p, y: tikhonov(p, y, mu=0.0, refine=5), "mu must be finite and > 0 when refine > 0"),
        (lambda p, y: tikhonov(p, y, refine=-1), "refine must be an int >= 0"),
        (lambda p, y: wiener(p, y * float("nan")), "image contains 30 NaN/Inf"),
        (lambda p, y: tikhonov(p, y[:5]), r"image must have shape \(6, 5\)"),
    ],
)
def test_named_errors(tiny, call, message):
    projector, image = tiny
    with pytest.raises(ValueError, match=message):
        call(projector, image)


def test_wiener_refuses_the_conventional_projector(conventional):
    # Tikhonov takes it (per lenslet-lattice frequency: test_lattice_tikhonov.py); Wiener does not.
    image = torch.ones(conventional.setup.projector.image_shape)
    with pytest.raises(NotImplementedError, match="shift-invariant projector with cached OTFs") as refused:
        wiener(conventional.setup.projector, image)
    assert "Richardson-Lucy" in str(refused.value) and "tikhonov" in str(refused.value)  # both run on it
    assert tikhonov(conventional.setup.projector, image).shape == conventional.setup.projector.volume_shape
