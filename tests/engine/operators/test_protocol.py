"""Every engine projector implements the Projector protocol, and the Fourier ones the Fourier protocols.

Run-time half: ``isinstance`` on the ``runtime_checkable`` protocols, the members' values
(shapes, dtype, device) and the contract behind them (``forward``/``adjoint`` map between
those shapes and are exact transposes: ``<A x, y> = <x, A^T y>``). The static half (mypy
accepts the projectors where a protocol is expected and rejects wrong types at a seam) is
``tests/test_typing.py``.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lfm_studio.engine.errors import require_device
from lfm_studio.engine.operators import (
    FourierProjector,
    Projector,
    PrunedFourierProjector,
    ShiftInvariantProjector,
)
from lfm_studio.engine.operators.binned import BinnedProjector
from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector
from lfm_studio.engine.operators.protocol import missing_members, protocol_members
from lfm_studio.engine.reconstruct import (
    FilteredBackProjector,
    poisson_nll,
    reconstruct_frame,
    richardson_lucy,
    tikhonov,
    wiener,
)


def _random(shape: tuple[int, ...], seed: int) -> torch.Tensor:
    return torch.rand(shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def shift_invariant() -> ShiftInvariantProjector:
    return ShiftInvariantProjector(_random((3, 12, 10), 1), (7, 6), depth_chunk=2)


def lenslet_lattice() -> LensletLatticeProjector:
    # 2 depths, 3 x 3 sub-positions, 3 x 3 pixels per lenslet, reach 1 lenslet (9 = 3 Q), 4 x 4 lenslets.
    return LensletLatticeProjector([([0, 1], _random((2, 3, 3, 9, 9), 2))], 2, (4, 4), 3)


def binned() -> BinnedProjector:
    return BinnedProjector(shift_invariant(), 2)


PROJECTORS = {"shift-invariant": shift_invariant, "lenslet-lattice": lenslet_lattice, "binned": binned}


@pytest.mark.parametrize("make", PROJECTORS.values(), ids=PROJECTORS.keys())
def test_every_engine_projector_is_a_projector_in_float64_on_the_cpu(make):
    projector = make()
    assert isinstance(projector, Projector)
    assert missing_members(projector, Projector) == []
    assert projector.dtype == torch.float64
    assert projector.device == torch.device("cpu")


@pytest.mark.parametrize("make", PROJECTORS.values(), ids=PROJECTORS.keys())
def test_forward_and_adjoint_map_between_the_declared_shapes_and_are_transposes(make):
    projector = make()
    x = _random(projector.volume_shape, 3)
    y = _random(projector.image_shape, 4)
    ax, aty = projector.forward(x), projector.adjoint(y)
    assert tuple(ax.shape) == projector.image_shape
    assert tuple(aty.shape) == projector.volume_shape
    assert ax.dtype == aty.dtype == projector.dtype
    # <A x, y> = <x, A^T y>: two different sums of positive terms, float64 rounding only.
    assert float((ax * y).sum()) == pytest.approx(float((x * aty).sum()), rel=1e-12)


@pytest.mark.parametrize("make", PROJECTORS.values(), ids=PROJECTORS.keys())
def test_forward_and_adjoint_take_numpy_arrays_as_the_tensors_they_hold(make):
    projector = make()
    x = _random(projector.volume_shape, 3)
    y = _random(projector.image_shape, 4)
    assert torch.equal(projector.forward(x.numpy().astype(np.float32)), projector.forward(x.float()))
    assert torch.equal(projector.adjoint(y.numpy()), projector.adjoint(y))
    with pytest.raises(ValueError, match=r"volume must have shape"):
        projector.forward(x.numpy()[:-1])
    with pytest.raises(ValueError, match=r"volume must be real \(intensities\)"):
        projector.forward(x.numpy() * 1j)


ON_DEVICE = {
    "shift-invariant": lambda device: ShiftInvariantProjector(_random((3, 12, 10), 1).to(device), (7, 6)),
    "lenslet-lattice": lambda device: LensletLatticeProjector(
        [([0, 1], _random((2, 3, 3, 9, 9), 2).to(device))], 2, (4, 4), 3
    ),
    "binned": lambda device: BinnedProjector(
        ShiftInvariantProjector(_random((3, 12, 10), 1).to(device), (7, 6)), 2
    ),
}


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
@pytest.mark.parametrize("make", ON_DEVICE.values(), ids=ON_DEVICE.keys())
def test_numpy_input_to_a_cuda_projector_is_moved_to_its_device(make):
    projector = make("cuda")
    x = _random(projector.volume_shape, 3)
    y = _random(projector.image_shape, 4)
    image, volume = projector.forward(x.numpy()), projector.adjoint(y.numpy())
    assert image.device.type == volume.device.type == "cuda"
    # The same inputs on the same device, but CUDA kernels may sum in another order between calls
    # (the lenslet lattice's transposed convolution differed in the last bits on an H200): a tolerance.
    torch.testing.assert_close(
        image, projector.forward(x.cuda()), rtol=1e-5, atol=1e-6 * float(image.abs().max())
    )
    torch.testing.assert_close(
        volume, projector.adjoint(y.cuda()), rtol=1e-5, atol=1e-6 * float(volume.abs().max())
    )
    assert require_device("cuda:0") == torch.device("cuda:0")
    with pytest.raises(ValueError, match=r"this machine has \d+ CUDA device\(s\), numbered from 0\. Fix"):
        require_device(f"cuda:{torch.cuda.device_count()}")


def test_only_the_shift_invariant_projector_is_a_fourier_projector():
    fourier = shift_invariant()
    assert isinstance(fourier, FourierProjector)
    assert isinstance(fourier, PrunedFourierProjector)
    for other in (lenslet_lattice(), binned()):
        assert not isinstance(other, FourierProjector)
        assert "otf" in missing_members(other, FourierProjector)


def test_fourier_members_describe_the_projector_geometry():
    projector = shift_invariant()  # PSF 12 x 10, volume 7 x 6: full convolution 18 x 15
    assert projector.full_shape == (18, 15)
    assert all(f >= n for f, n in zip(projector.fft_shape, projector.full_shape, strict=True))
    assert tuple(projector.otf.shape) == (3, projector.fft_shape[0], projector.fft_shape[1] // 2 + 1)
    assert torch.equal(projector.otf_t.transpose(-2, -1), projector.otf)
    # Chunks of 2 depths cover the 3 depths once, in order.
    assert list(projector.depth_chunks()) == [slice(0, 2), slice(2, 3)]
    # The matched filter conj(otf_t) through filtered_adjoint is the adjoint.
    y = _random(projector.image_shape, 5)
    assert torch.allclose(projector.filtered_adjoint(y, projector.otf_t.conj()), projector.adjoint(y))


def test_binned_projector_takes_dtype_and_device_from_its_inner_projector():
    inner = ShiftInvariantProjector(_random((2, 8, 8), 6).float(), (5, 5))
    outer = BinnedProjector(inner, 2)
    assert outer.dtype == torch.float32 and outer.device == inner.device
    assert outer.volume_shape == inner.volume_shape and outer.image_shape == (4, 4)


def test_missing_members_names_what_an_object_lacks_in_declaration_order():
    assert protocol_members(Projector) == (
        "volume_shape",
        "image_shape",
        "device",
        "dtype",
        "forward",
        "adjoint",
    )
    assert missing_members(object(), Projector) == list(protocol_members(Projector))

    class HalfProjector:
        volume_shape, image_shape = (1, 2, 2), (2, 2)

        def forward(self, volume: torch.Tensor) -> torch.Tensor:
            return volume.sum(0)

    assert missing_members(HalfProjector(), Projector) == ["device", "dtype", "adjoint"]
    assert not isinstance(HalfProjector(), Projector)
    fourier_only = protocol_members(FourierProjector)[len(protocol_members(Projector)) :]
    assert fourier_only == ("otf", "fft_shape", "full_shape", "depth_chunks")


@pytest.mark.parametrize("make", PROJECTORS.values(), ids=PROJECTORS.keys())
def test_richardson_lucy_runs_on_every_projector_through_the_protocol(make):
    projector = make()
    image = projector.forward(_random(projector.volume_shape, 7)).clamp_min(0.0)
    start = torch.full(
        projector.volume_shape, float(image.sum()) / float(projector.adjoint(torch.ones_like(image)).sum())
    )
    estimate = richardson_lucy(projector, image, iterations=5)
    assert tuple(estimate.shape) == projector.volume_shape and estimate.dtype == projector.dtype
    # EM: five RL steps from the flux-matched uniform start lower the Poisson NLL.
    assert poisson_nll(projector, estimate, image) < poisson_nll(projector, start, image)


@pytest.mark.parametrize(
    ("make", "method"),
    [(lenslet_lattice, "wiener"), (binned, "wiener"), (binned, "tikhonov")],
    ids=["lenslet-lattice-wiener", "binned-wiener", "binned-tikhonov"],
)  # Tikhonov also takes the lenslet lattice (per lattice frequency: test_lattice_tikhonov.py)
def test_fourier_methods_name_what_a_non_fourier_projector_lacks(make, method):
    projector = make()
    image = torch.ones(projector.image_shape, dtype=torch.float64)
    what = {"wiener": "Wiener deconvolution", "tikhonov": "Tikhonov reconstruction"}[method]
    message = (
        rf"{what} needs a laterally shift-invariant projector with cached OTFs .* "
        rf"{type(projector).__name__} has no otf, fft_shape, full_shape, depth_chunks\. Fix: use Richardson-Lucy"
    )
    # Through the registry the method refuses the projector before running, naming it in words (no
    # class name) and the methods that take it.
    refusal = r"needs a laterally shift-invariant \(Fourier LFM\) projector .*; got a .*projector .*\. Fix: choose rl"
    with pytest.raises(ValueError, match=refusal) as refused:
        reconstruct_frame(projector, image, method=method)
    assert type(projector).__name__ not in str(refused.value)
    with pytest.raises(NotImplementedError, match=message):
        {"wiener": wiener, "tikhonov": tikhonov}[method](projector, image)


class OnlyFourier:
    """A shift-invariant projector seen through FourierProjector's members only (no pruned adjoint)."""

    def __init__(self, inner: ShiftInvariantProjector) -> None:
        self.inner = inner
        self.volume_shape, self.image_shape = inner.volume_shape, inner.image_shape
        self.device, self.dtype = inner.device, inner.dtype
        self.otf, self.fft_shape, self.full_shape = inner.otf, inner.fft_shape, inner.full_shape

    def forward(self, volume: torch.Tensor) -> torch.Tensor:
        return self.inner.forward(volume)

    def adjoint(self, image: torch.Tensor) -> torch.Tensor:
        return self.inner.adjoint(image)

    def depth_chunks(self):
        return self.inner.depth_chunks()


def test_fourier_solvers_need_only_the_fourier_protocol():
    inner = shift_invariant()
    plain = OnlyFourier(inner)
    assert isinstance(plain, FourierProjector) and not isinstance(plain, PrunedFourierProjector)
    y = _random(inner.image_shape, 8)
    # Without filtered_adjoint the back projector runs its own FFTs: conj(otf) still gives A^T.
    matched = FilteredBackProjector(plain, inner.otf.conj().resolve_conj())
    expected = inner.adjoint(y)
    assert torch.allclose(matched(y), expected, rtol=0, atol=1e-12 * float(expected.abs().max()))
    # Wiener and Tikhonov read only FourierProjector members: same result as on the projector itself.
    torch.testing.assert_close(wiener(plain, y, snr=20.0), wiener(inner, y, snr=20.0), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(
        tikhonov(plain, y, mu=1e-2), tikhonov(inner, y, mu=1e-2), rtol=1e-12, atol=1e-12
    )
