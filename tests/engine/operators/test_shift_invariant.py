"""Shift-invariant projector: matches direct convolution; A^T is the exact adjoint; gradients."""

from __future__ import annotations

import bisect

import numpy as np
import pytest
import torch
from scipy.signal import convolve

from lfm_studio.engine.operators import ShiftInvariantProjector
from lfm_studio.engine.operators.fft_sizes import next_fast_length


def _random(shape, seed, dtype=torch.float64):
    return torch.rand(shape, generator=torch.Generator().manual_seed(seed), dtype=dtype)


@pytest.mark.parametrize(
    ("volume_shape", "psf_shape"), [((7, 9), (16, 12)), ((16, 16), (5, 6)), ((10, 11), (10, 11))]
)
def test_forward_equals_direct_linear_convolution_cropped_to_the_sensor(volume_shape, psf_shape):
    psf = _random((3, *psf_shape), 1)
    volume = _random((3, *volume_shape), 2)
    projector = ShiftInvariantProjector(psf, volume_shape)
    full = sum(convolve(volume[z].numpy(), psf[z].numpy(), mode="full") for z in range(3))
    oy = (full.shape[0] - psf_shape[0] + 1) // 2
    ox = (full.shape[1] - psf_shape[1] + 1) // 2
    expected = full[oy : oy + psf_shape[0], ox : ox + psf_shape[1]]
    # float64 FFT convolution vs direct sums: rounding ~1e-15 relative per term.
    assert np.allclose(projector.forward(volume).numpy(), expected, rtol=1e-12, atol=1e-12)


def test_a_point_in_the_volume_centre_images_as_its_psf_centred():
    psf = _random((2, 9, 9), 3)
    volume = torch.zeros(2, 5, 5, dtype=torch.float64)
    volume[1, 2, 2] = 1.0
    image = ShiftInvariantProjector(psf, (5, 5)).forward(volume)
    assert torch.allclose(image, psf[1], atol=1e-13)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("chunk", [None, 1, 2])
def test_adjoint_identity_on_random_inputs(dtype, chunk):
    psf = _random((5, 20, 17), 4, dtype)
    projector = ShiftInvariantProjector(psf, (8, 11), depth_chunk=chunk)
    x = _random((5, 8, 11), 5, dtype)
    y = _random((20, 17), 6, dtype)
    lhs = float((projector.forward(x).double() * y.double()).sum())
    rhs = float((x.double() * projector.adjoint(y).double()).sum())
    # float32: about 1e-7 relative per FFT pass, a few passes -> 1e-5 bound.
    tol = 1e-5 if dtype == torch.float32 else 1e-12
    assert abs(lhs - rhs) <= tol * abs(lhs)


def test_gradcheck_forward_and_adjoint():
    psf = _random((2, 6, 5), 7)
    projector = ShiftInvariantProjector(psf, (4, 3))
    x = _random((2, 4, 3), 8).requires_grad_()
    y = _random((6, 5), 9).requires_grad_()
    assert torch.autograd.gradcheck(projector.forward, (x,))
    assert torch.autograd.gradcheck(projector.adjoint, (y,))


def test_gradient_reaches_the_psf():
    psf = _random((2, 6, 5), 10).requires_grad_()
    x = _random((2, 4, 3), 11)
    assert torch.autograd.gradcheck(lambda h: ShiftInvariantProjector(h, (4, 3)).forward(x), (psf,))


def test_named_errors():
    psf = _random((2, 6, 5), 12)
    with pytest.raises(ValueError, match=r"volume must have shape \(2, 4, 3\)"):
        ShiftInvariantProjector(psf, (4, 3)).forward(torch.zeros(2, 4, 4, dtype=torch.float64))
    with pytest.raises(ValueError, match="psf is all zero"):
        ShiftInvariantProjector(torch.zeros(2, 6, 5), (4, 3))
    bad = psf.clone()
    bad[0, 0, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN/Inf"):
        ShiftInvariantProjector(bad, (4, 3))


def test_next_fast_length():
    assert [next_fast_length(n) for n in (1, 7, 11, 13, 97, 2048, 2049)] == [1, 8, 12, 15, 100, 2048, 2160]


def test_next_fast_length_is_the_next_smooth_number_even_where_they_are_far_apart():
    # Every 2-3-5-smooth number below 2^64, sorted: the answer is the first one >= n. Near 1e13
    # they lie ~1e9 apart, where counting up from n (the old loop) never finished.
    limit = 2**64
    smooth = sorted(
        2**a * 3**b * 5**c
        for c in range(28)
        for b in range(41)
        for a in range(65)
        if 2**a * 3**b * 5**c < limit
    )
    for n in (*range(1, 3000), 10**13 + 1, 2**62 + 1, 3**30 + 7, 5**20 - 1):
        assert next_fast_length(n) == smooth[bisect.bisect_left(smooth, n)], n


@pytest.mark.parametrize("chunk", [1, 2, 3, 5])
def test_chunked_setup_gives_the_zero_padded_rfft2_of_every_psf(chunk):
    """The OTFs built chunk by chunk of depths equal numpy's rfft2 of each zero-padded PSF."""
    psf = _random((5, 12, 9), 13)
    projector = ShiftInvariantProjector(psf, (6, 7), depth_chunk=chunk)
    expected = np.fft.rfft2(psf.numpy(), s=projector.fft_shape, axes=(-2, -1))
    # float64 FFTs of O(1) data with ~100 terms: rounding ~1e-14 absolute.
    assert np.allclose(projector.otf.numpy(), expected, rtol=1e-12, atol=1e-12)


def test_operator_does_not_depend_on_the_setup_chunk():
    """One depth per chunk and all depths in one chunk give the same A x, A^T y and adjoint identity."""
    psf = _random((6, 15, 13), 14, torch.float32)
    x = _random((6, 7, 8), 15, torch.float32)
    y = _random((15, 13), 16, torch.float32)
    single, whole = (ShiftInvariantProjector(psf, (7, 8), depth_chunk=c) for c in (1, 6))
    # float32 FFT chains of O(1) data: a few 1e-7 relative per pass.
    assert torch.allclose(single.forward(x), whole.forward(x), rtol=1e-5, atol=1e-5)
    assert torch.allclose(single.adjoint(y), whole.adjoint(y), rtol=1e-5, atol=1e-5)
    lhs = float((single.forward(x).double() * y.double()).sum())
    rhs = float((x.double() * single.adjoint(y).double()).sum())
    assert abs(lhs - rhs) <= 1e-5 * abs(lhs)


def test_gradient_reaches_the_psf_through_a_chunked_setup():
    psf = _random((3, 6, 5), 17).requires_grad_()
    x = _random((3, 4, 3), 18)
    assert torch.autograd.gradcheck(
        lambda h: ShiftInvariantProjector(h, (4, 3), depth_chunk=1).forward(x), (psf,)
    )


@pytest.mark.parametrize("chunk", [1, 2, 3])
def test_buffered_no_grad_path_equals_the_autograd_path(chunk):
    """Without autograd, forward/adjoint reuse zeroed windows and product buffers across chunks
    (a shorter last chunk included); they must give what the tracked (pure-function) path gives,
    and the tracked results must equal direct convolutions (an independent reference)."""
    g = torch.Generator().manual_seed(4)
    psf = torch.rand((5, 13, 11), generator=g)
    volume = torch.rand((5, 6, 7), generator=g)
    image = torch.rand((13, 11), generator=g)
    projector = ShiftInvariantProjector(psf, (6, 7), depth_chunk=chunk)
    with torch.no_grad():
        fast_forward, fast_adjoint = projector.forward(volume), projector.adjoint(image)
    tracked_volume, tracked_image = volume.clone().requires_grad_(), image.clone().requires_grad_()
    slow_forward = projector.forward(tracked_volume)
    slow_adjoint = projector.adjoint(tracked_image)
    assert slow_forward.requires_grad and slow_adjoint.requires_grad  # really the other path
    torch.testing.assert_close(
        fast_forward, slow_forward.detach(), rtol=1e-5, atol=1e-5 * float(fast_forward.abs().max())
    )
    torch.testing.assert_close(
        fast_adjoint, slow_adjoint.detach(), rtol=1e-5, atol=1e-5 * float(fast_adjoint.abs().max())
    )
    full = sum(convolve(volume[z].double().numpy(), psf[z].double().numpy()) for z in range(5))
    oy, ox = (full.shape[0] - 13 + 1) // 2, (full.shape[1] - 11 + 1) // 2
    np.testing.assert_allclose(
        fast_forward.double().numpy(), full[oy : oy + 13, ox : ox + 11], rtol=1e-4, atol=1e-5
    )
    # the second call reuses nothing stale: a different volume gives its own image
    with torch.no_grad():
        again = projector.forward(2.0 * volume)
    torch.testing.assert_close(
        again, 2.0 * fast_forward, rtol=1e-5, atol=1e-5 * float(fast_forward.abs().max())
    )
