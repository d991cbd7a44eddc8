"""Regression guard for the torch CPU FFT scaling bug (docs/platform.md).

torch 2.13.0+cpu with 2 threads returns ``ifft2(fft2(x))`` of a 2048 x 2048
complex64 array scaled by 1/N^2. Our FFT module must round-trip and satisfy
Parseval at every size, batched or not, complex64 and complex128, 1 and 2 threads.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lfm_studio.engine import fft

# Relative round-trip error of an FFT pair is about eps * log2(N); 1e-5 (complex64)
# and 1e-12 (complex128) leave an order of magnitude of margin at N = 4096^2, while
# the bug gives an error of 1.0.
TOLERANCE = {torch.complex64: 1e-5, torch.complex128: 1e-12}


@pytest.fixture(params=[1, 2], ids=["1thread", "2threads"])
def threads(request):
    old = torch.get_num_threads()
    torch.set_num_threads(request.param)
    yield request.param
    torch.set_num_threads(old)


CASES = [(512, False), (1024, False), (2048, False), (2048, True), (4096, False)]


@pytest.mark.parametrize("dtype", [torch.complex64, torch.complex128], ids=["c64", "c128"])
@pytest.mark.parametrize(("n", "batched"), CASES, ids=[f"{n}{'b' if b else ''}" for n, b in CASES])
def test_round_trip_and_parseval(threads, n, batched, dtype):
    if n == 4096 and dtype == torch.complex128 and threads == 1:
        pytest.skip("4096^2 complex128 at 1 thread adds time, not coverage (same code path as 2 threads)")
    gen = torch.Generator().manual_seed(n)
    shape = (2, n, n) if batched else (n, n)
    x = torch.randn(shape, dtype=dtype, generator=gen)
    spectrum = fft.fft2(x)
    back = fft.ifft2(spectrum)
    tol = TOLERANCE[dtype]
    assert float((back - x).abs().max() / x.abs().max()) < tol
    energy_ratio = float(spectrum.abs().pow(2).sum() / (n * n) / x.abs().pow(2).sum())
    assert abs(energy_ratio - 1.0) < tol


@pytest.mark.parametrize("n", [2048, 1000])
def test_real_round_trip(threads, n):
    gen = torch.Generator().manual_seed(1)
    x = torch.randn(n, n, generator=gen)
    back = fft.irfft2(fft.rfft2(x), s=(n, n))
    assert float((back - x).abs().max() / x.abs().max()) < 1e-5


def test_matches_numpy_convention_and_centering():
    np = pytest.importorskip("numpy")
    gen = torch.Generator().manual_seed(3)
    x = torch.randn(6, 5, dtype=torch.complex128, generator=gen)
    ref = np.fft.fftshift(np.fft.fft2(np.fft.ifftshift(x.numpy())))
    assert np.allclose(fft.centered_fft2(x).numpy(), ref, atol=1e-12)
    assert torch.allclose(fft.centered_ifft2(fft.centered_fft2(x)), x, atol=1e-12)
    # A delta at the centre index N // 2 has a flat, real spectrum.
    delta = torch.zeros(6, 5, dtype=torch.complex128)
    delta[3, 2] = 1.0
    assert torch.allclose(fft.centered_fft2(delta), torch.ones(6, 5, dtype=torch.complex128))


@pytest.mark.parametrize("n", [2048, 2400, 1000])
def test_separable_1d_transforms_equal_the_2d_real_transform(threads, n):
    # The projector applies rfft along x then fft along y (unscaled), and the inverses
    # unscaled with one 1/N: this must equal rfft2 / irfft2 at every size, incl. 2048.
    gen = torch.Generator().manual_seed(n)
    x = torch.randn(3, 64, n, generator=gen)
    spectrum = fft.fft_along(fft.rfft_along(x, n, dim=-1), 128, dim=-2)
    reference = fft.rfft2(torch.nn.functional.pad(x, (0, 0, 0, 64)))
    assert float((spectrum - reference).abs().max() / reference.abs().max()) < 1e-5
    back = fft.irfft_along_unscaled(fft.ifft_along_unscaled(spectrum, dim=-2), n, dim=-1) / (128 * n)
    assert float((back[:, :64] - x).abs().max() / x.abs().max()) < 1e-5


@pytest.mark.parametrize("dtype", [torch.complex64, torch.complex128])
def test_column_transforms_equal_numpy_with_and_without_autograd(dtype):
    """column_fft / column_ifft_unscaled are numpy's unnormalised DFTs along the last dim, tracked or
    not (the projector's no-grad and autograd paths), and stay differentiable."""
    rng = np.random.default_rng(3)
    block = rng.standard_normal((3, 5, 48)) + 1j * rng.standard_normal((3, 5, 48))
    x = torch.from_numpy(block).to(dtype)
    tol = 1e-5 if dtype == torch.complex64 else 1e-12
    reference_fft, reference_ifft = np.fft.fft(block, axis=-1), np.fft.ifft(block, axis=-1) * 48
    for tracked in (False, True):
        source = x.clone().requires_grad_(tracked)
        forward, inverse = fft.column_fft(source), fft.column_ifft_unscaled(source)
        assert forward.requires_grad == tracked and inverse.requires_grad == tracked
        scale = np.abs(reference_fft).max()
        np.testing.assert_allclose(forward.detach().numpy(), reference_fft, rtol=0, atol=tol * scale)
        np.testing.assert_allclose(inverse.detach().numpy(), reference_ifft, rtol=0, atol=tol * scale)
    # a strided (transposed) input and a lazily conjugated one go through the same definitions
    strided = x.transpose(-2, -1)
    np.testing.assert_allclose(
        fft.column_fft(strided).numpy(), np.fft.fft(block.transpose(0, 2, 1), axis=-1), atol=tol * scale
    )
    np.testing.assert_allclose(
        fft.column_fft(x.conj()).numpy(), np.fft.fft(block.conj(), axis=-1), atol=tol * scale
    )
