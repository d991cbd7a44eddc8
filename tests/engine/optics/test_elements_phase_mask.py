"""Phase masks (thesis eq. 3.19): apply_phase, PhaseMask trainable/buffer, wrap, quantisation."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.phase_mask import PhaseMask, apply_phase, quantize_phase
from lfm_studio.engine.optics.sources import plane_wave
from lfm_studio.engine.units import nm, um

WAVELENGTH = 500 * nm
GRID = Grid(16, 2 * um)


def _random_field(dtype=torch.complex128, seed=0) -> Field:
    gen = torch.Generator().manual_seed(seed)
    return Field(torch.randn((2, 16, 16), dtype=dtype, generator=gen), GRID, WAVELENGTH)


def test_apply_phase_multiplies_by_exp_j_phase_in_float64():
    field = _random_field(torch.complex64)
    # Large phases (up to 1e4 rad, float64): a float32 phase would err by ~1e-3 rad.
    phase = torch.linspace(0, 1e4, 256, dtype=torch.float64).reshape(16, 16)
    out = apply_phase(field, phase)
    expected = field.data.to(torch.complex128) * torch.exp(1j * phase)
    assert out.dtype == torch.complex64
    # complex64 rounding of the product: ~1e-7 relative (|data| < 5).
    torch.testing.assert_close(out.data.to(torch.complex128), expected, rtol=0, atol=5e-6)
    torch.testing.assert_close(apply_phase(field, math.pi).data, -field.data, rtol=0, atol=1e-6)


def test_trainable_is_a_parameter_and_fixed_is_a_buffer():
    phase = torch.rand(16, 16, dtype=torch.float64)
    trainable = PhaseMask(GRID, phase, trainable=True)
    fixed = PhaseMask(GRID, phase)
    assert trainable.trainable and [n for n, _ in trainable.named_parameters()] == ["phase"]
    assert not fixed.trainable and list(fixed.parameters()) == [] and "phase" in dict(fixed.named_buffers())
    assert "phase" in fixed.state_dict() and "phase" in trainable.state_dict()
    phase.add_(1.0)  # the module holds a copy
    assert torch.equal(trainable.phase.detach(), fixed.phase) and float(fixed.phase.max()) < 1.0
    assert PhaseMask(GRID).phase.dtype == torch.float64 and float(PhaseMask(GRID).phase.abs().sum()) == 0.0
    field = _random_field()
    torch.testing.assert_close(fixed(field).data, apply_phase(field, fixed.phase).data, rtol=0, atol=0)


def test_gradient_reaches_the_phase():
    # Through the quantised (straight-through) forward pass: an 8-level SLM.
    gen = torch.Generator().manual_seed(5)
    mask = PhaseMask(GRID, torch.rand((16, 16), generator=gen) * 6, trainable=True, levels=8)
    field = plane_wave(GRID, WAVELENGTH)
    loss = mask(field).data.sum().abs() ** 2  # on-axis far-field intensity
    loss.backward()
    assert mask.phase.grad is not None and float(mask.phase.grad.abs().sum()) > 0.0
    # The straight-through estimator passes the gradient unchanged: d(sum(w * phi_q))/d phi = w.
    mask.phase.grad = None
    weights = torch.rand((16, 16), generator=gen)
    (mask.effective_phase() * weights).sum().backward()
    torch.testing.assert_close(mask.phase.grad, weights)


def test_wrap_and_quantise_like_an_slm():
    phase = torch.linspace(-10.0, 10.0, 256, dtype=torch.float64).reshape(16, 16)
    wrapped = PhaseMask(GRID, phase, wrap=True).effective_phase()
    assert float(wrapped.min()) >= 0.0 and float(wrapped.max()) < 2 * math.pi
    field = _random_field()
    # wrapping does not change the field (exp is 2 pi periodic), to float64 rounding
    torch.testing.assert_close(PhaseMask(GRID, phase, wrap=True)(field).data, apply_phase(field, phase).data)
    levels = 8
    mask = PhaseMask(GRID, phase, levels=levels)
    assert mask.wrap  # quantisation implies wrapping
    quantised = mask.effective_phase()
    step = 2 * math.pi / levels
    steps = quantised / step
    torch.testing.assert_close(steps, torch.round(steps), rtol=0, atol=1e-12)  # on the levels
    assert int(torch.round(steps).max()) <= levels - 1 and int(torch.round(steps).min()) >= 0
    assert len(torch.unique(torch.round(steps))) == levels  # a ramp over 3 turns hits every level
    # nearest level, circularly: |exp(j q) - exp(j w)| <= 2 sin(step / 4)
    distance = (torch.exp(1j * quantised) - torch.exp(1j * wrapped)).abs()
    assert float(distance.max()) <= 2 * math.sin(step / 4) + 1e-12


def test_quantize_phase_straight_through_gradient_and_levels_check():
    phase = torch.tensor([0.1, 3.0, 6.2, -0.3], dtype=torch.float64, requires_grad=True)
    out = quantize_phase(phase, 4)
    torch.testing.assert_close(out.detach(), torch.tensor([0.0, math.pi, 0.0, 0.0], dtype=torch.float64))
    out.sum().backward()
    torch.testing.assert_close(phase.grad, torch.ones(4, dtype=torch.float64))
    with pytest.raises(ValueError, match="levels must be an integer >= 2; got 1"):
        PhaseMask(GRID, levels=1)


def test_named_errors():
    mask = PhaseMask(GRID)
    other = Field(torch.ones((16, 16), dtype=torch.complex64), Grid(16, 3 * um), WAVELENGTH)
    with pytest.raises(ValueError, match=r"PhaseMask grid .* does not match the field grid"):
        mask(other)
    with pytest.raises(ValueError, match=r"phase shape \(8, 8\) does not match the grid shape \(16, 16\)"):
        PhaseMask(GRID, torch.zeros(8, 8))
    with pytest.raises(TypeError, match="phase must be a real floating tensor"):
        PhaseMask(GRID, torch.zeros(16, 16, dtype=torch.complex64))
    bad = torch.zeros(16, 16)
    bad[0, 0] = float("nan")
    with pytest.raises(ValueError, match="phase contains 1 NaN/Inf"):
        PhaseMask(GRID, bad)
    with pytest.raises(ValueError, match="phase contains 1 NaN/Inf"):
        apply_phase(plane_wave(GRID, WAVELENGTH), bad)
    with pytest.raises(ValueError, match=r"phase shape \(4, 4\) does not end in the field's grid shape"):
        apply_phase(plane_wave(GRID, WAVELENGTH), torch.zeros(4, 4))
    with pytest.raises(TypeError, match="phase must be real"):
        apply_phase(plane_wave(GRID, WAVELENGTH), torch.zeros(16, 16, dtype=torch.complex64))


def test_gradcheck_apply_phase_and_phase_mask():
    gen = torch.Generator().manual_seed(4)
    data = torch.randn((16, 16), dtype=torch.complex128, generator=gen, requires_grad=True)
    phase = (4 * torch.rand((16, 16), dtype=torch.float64, generator=gen)).requires_grad_()

    def functional(data, phase):
        return apply_phase(Field(data, GRID, WAVELENGTH), phase).data

    assert torch.autograd.gradcheck(functional, (data, phase), fast_mode=True)
    mask = PhaseMask(GRID, trainable=True, wrap=True)
    field = Field(data.detach(), GRID, WAVELENGTH)

    def module(phase):
        # phase in (0, 4): away from the wrap discontinuity at 2 pi by > eps
        return torch.func.functional_call(mask, {"phase": phase + 0.5}, (field,)).data

    assert torch.autograd.gradcheck(module, (phase,), fast_mode=True)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu():
    phase = torch.rand(16, 16, dtype=torch.float64)
    mask = PhaseMask(GRID, phase, trainable=True, levels=16)
    field = _random_field(torch.complex64)
    cpu = mask(field).data
    gpu = mask.to("cuda")(field.to("cuda")).data
    assert gpu.device.type == "cuda"
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=0, atol=1e-6)
