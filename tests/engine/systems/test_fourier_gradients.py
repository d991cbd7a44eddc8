"""Gradients through the per-lenslet Fourier PSF, the shift-invariant projector and unrolled RL.

Tiny float64 system: 20x/0.12 water objective (f_obj = 9 mm), Fourier lens 60 mm (relayed
pupil radius 0.36 mm on the MLA, so the rim cuts the outer lenslets and the NA has a
gradient), three 0.25 mm lenslets (two circles, one square) of 5 mm focal length, camera
5 mm behind, 8 um pixels, 2 sub-samples: windows of 30 samples. No lenslet sits on the axis
(its centre sample would fall on a knot of the bilinear phase mask: a kink in the centre
gradient). Parameters are passed in mm / um / plain numbers so that gradcheck's
finite-difference step (1e-6) is well scaled.
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

from lfm_studio.engine.operators.shift_invariant import ShiftInvariantProjector
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.optics.phase_mask import PhaseMask
from lfm_studio.engine.reconstruct.unrolled import richardson_lucy_unrolled
from lfm_studio.engine.systems.fourier_parameters import FourierParameters
from lfm_studio.engine.systems.fourier_psf import FourierAccuracy, FourierPSFReport, fourier_psf_stack
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem
from lfm_studio.engine.systems.lenslet_cache import LensletCache
from lfm_studio.engine.units import mm, nm, um

F64 = torch.float64
CENTRES = ((0.013 * mm, -0.021 * mm), (0.3 * mm, 0.05 * mm), (-0.12 * mm, -0.28 * mm))
SHAPES = ("circle", "square", "circle")
SYSTEM = FourierLFMSystem(
    ObjectiveLens(20.0, 0.12, 1.33, 180 * mm),
    60 * mm,
    MicrolensArray(tuple(Lenslet(c, 0.25 * mm, 5 * mm, s) for c, s in zip(CENTRES, SHAPES, strict=True))),
    5 * mm,
    8 * um,
    (96, 96),
    525 * nm,
)
ACC = FourierAccuracy(method="per_lenslet", oversampling=2, margin_airy=4, dtype=F64)
DEPTHS = (-4 * um, 3 * um)
VOLUME = (12, 12)
PSF_SCALE = 1e-3  # the stack sums to ~6e-4 per depth; scaled to order one for the RL


def _nominal() -> list[torch.Tensor]:
    """f (mm), D (mm), centres (mm), wavelength (um), NA, d (mm), f_fourier (mm)."""
    values = [
        [5.0, 5.0, 5.0],
        [0.25, 0.25, 0.25],
        [[x / mm, y / mm] for x, y in CENTRES],
        0.525,
        0.12,
        5.0,
        60.0,
    ]
    return [torch.tensor(v, dtype=F64, requires_grad=True) for v in values]


def _parameters(f, diameter, centres, wavelength, na, d, fourier) -> FourierParameters:
    return FourierParameters(
        focal_lengths=f * mm,
        aperture_diameters=diameter * mm,
        centers=centres * mm,
        wavelength=wavelength * um,
        numerical_aperture=na,
        mla_to_camera=d * mm,
        fourier_focal_length=fourier * mm,
    )


def _psf(*values, mask=None, cache=None, report=None) -> torch.Tensor:
    parameters = dataclasses.replace(_parameters(*values), pupil_phase=mask)
    stack = fourier_psf_stack(SYSTEM, DEPTHS, accuracy=ACC, parameters=parameters, cache=cache, report=report)
    return stack.data / PSF_SCALE


def test_parameters_at_the_system_values_reproduce_the_plain_stack():
    plain = fourier_psf_stack(SYSTEM, DEPTHS, accuracy=ACC).data / PSF_SCALE
    with torch.no_grad():
        overridden = _psf(*_nominal())
    # The soft (antialiased) pupil rim that an NA parameter brings changes only rim samples.
    assert torch.allclose(overridden, plain, rtol=0, atol=0.02 * float(plain.max()))
    without_na = [v.detach() for v in _nominal()]
    params = dataclasses.replace(_parameters(*without_na), numerical_aperture=None)
    same = fourier_psf_stack(SYSTEM, DEPTHS, accuracy=ACC, parameters=params).data / PSF_SCALE
    error = float((same - plain).abs().max() / plain.max())
    assert error < 1e-9, error


def test_gradcheck_psf_projector_unrolled_rl_loss():
    gen = torch.Generator().manual_seed(0)
    truth = torch.rand(len(DEPTHS), *VOLUME, generator=gen, dtype=F64) + 0.5
    with torch.no_grad():
        image = ShiftInvariantProjector(_psf(*_nominal()), VOLUME).forward(truth)
    weights = torch.rand(len(DEPTHS), *VOLUME, generator=gen, dtype=F64)

    # A coarse SLM phase on the MLA plane (6 x 6 samples of 150 um over all lenslets); its
    # trainable phase is the last gradcheck input (perturbed in place, so the mask sees it).
    mask = PhaseMask(Grid(6, 150 * um), 0.5 * torch.randn(6, 6, generator=gen, dtype=F64), trainable=True)

    def loss(*values):
        *optics, phase = values
        assert phase is mask.phase
        projector = ShiftInvariantProjector(_psf(*optics, mask=mask), VOLUME)
        return (weights * richardson_lucy_unrolled(projector, image, 3)).sum()

    inputs = _nominal()
    loss(*inputs, mask.phase).backward()
    for value in inputs:  # every parameter moves the loss (the NA through the pupil rim)
        assert bool((value.grad != 0).all()), value.grad
    assert int((mask.phase.grad != 0).sum()) >= 12  # the mask samples next to lit patches
    inputs = (*_nominal(), mask.phase)
    assert torch.autograd.gradcheck(loss, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)


def test_centre_gradient_equals_a_central_difference_of_the_psf_loss():
    weights = torch.rand(
        len(DEPTHS), *SYSTEM.sensor_shape, generator=torch.Generator().manual_seed(2), dtype=F64
    )

    def loss(centres: torch.Tensor) -> torch.Tensor:
        values = _nominal()
        values[2] = centres
        return (weights * _psf(*values)).sum()

    centres = _nominal()[2]
    loss(centres).backward()
    h = 1e-5  # mm = 10 nm, about 1/800 pixel
    for lens in (1, 2):
        step = torch.zeros_like(centres)
        step[lens, 0] = h
        with torch.no_grad():
            numeric = (loss(centres + step) - loss(centres - step)) / (2 * h)
        assert float(centres.grad[lens, 0]) == pytest.approx(float(numeric), rel=1e-5)
        assert abs(float(numeric)) > 1e-3  # a real dependence, not a zero gradient


def test_a_pupil_phase_mask_gets_the_finite_difference_gradient():
    grid = Grid(32, 25 * um)  # 0.8 mm square on the MLA plane, over all three lenslets
    mask = PhaseMask(grid, 0.3 * torch.randn(32, 32, generator=torch.Generator().manual_seed(3), dtype=F64),
                     trainable=True)  # fmt: skip
    weights = torch.rand(
        len(DEPTHS), *SYSTEM.sensor_shape, generator=torch.Generator().manual_seed(4), dtype=F64
    )

    def loss() -> torch.Tensor:
        data = fourier_psf_stack(
            SYSTEM, DEPTHS, accuracy=ACC, parameters=FourierParameters(pupil_phase=mask)
        ).data
        return (weights * data / PSF_SCALE).sum()

    loss().backward()
    grad = mask.phase.grad.clone()
    assert int((grad != 0).sum()) > 20
    h = 1e-5
    for row, col in ((16, 16), (18, 28), (6, 11)):  # inside lenslets 0, 1 and 2
        with torch.no_grad():
            mask.phase[row, col] += h
            up = loss()
            mask.phase[row, col] -= 2 * h
            down = loss()
            mask.phase[row, col] += h
        numeric = float((up - down) / (2 * h))
        assert abs(numeric) > 1e-6
        assert float(grad[row, col]) == pytest.approx(numeric, rel=1e-5)


def test_cache_is_bypassed_when_an_input_requires_grad_and_used_otherwise():
    cache = LensletCache()
    for _ in range(2):
        report = FourierPSFReport()
        _psf(*_nominal(), cache=cache, report=report)
        assert report.lenslets_computed == [0, 1, 2] and report.lenslets_cached == []
    assert len(cache) == 0 and cache.misses == 0
    # A tensor focal length with requires_grad in the system itself also bypasses it.
    focal = torch.tensor(5 * mm, dtype=F64, requires_grad=True)
    lenses = tuple(
        Lenslet(c, 0.25 * mm, focal if i == 1 else 5 * mm, s)
        for i, (c, s) in enumerate(zip(CENTRES, SHAPES, strict=True))
    )
    graded = dataclasses.replace(SYSTEM, mla=MicrolensArray(lenses))
    report = FourierPSFReport()
    data = fourier_psf_stack(graded, DEPTHS, accuracy=ACC, cache=cache, report=report).data
    assert report.lenslets_cached == [] and len(cache) == 0
    data.sum().backward()
    assert focal.grad is not None and float(focal.grad) != 0.0
    # Without gradients the cache serves the second call.
    for expected_cached in ([], [0, 1, 2]):
        report = FourierPSFReport()
        fourier_psf_stack(SYSTEM, DEPTHS, accuracy=ACC, cache=cache, report=report)
        assert report.lenslets_cached == expected_cached


def test_parameter_errors_are_named():
    with pytest.raises(
        ValueError, match=r"FourierParameters.focal_lengths must be a real tensor of shape \(3,\)"
    ):
        fourier_psf_stack(
            SYSTEM, DEPTHS, accuracy=ACC, parameters=FourierParameters(focal_lengths=torch.ones(2))
        )
    with pytest.raises(ValueError, match="parameters need the per-lenslet path"):
        fourier_psf_stack(
            SYSTEM,
            DEPTHS,
            accuracy=FourierAccuracy(method="full_field", oversampling=2, dtype=F64),
            parameters=FourierParameters(wavelength=torch.tensor(525 * nm, dtype=F64)),
        )


def test_tensor_fields_of_the_objective_and_lenslets_get_central_difference_gradients():
    # Without FourierParameters: tensors held by the spec objects themselves (ObjectiveLens and
    # Lenslet accept 0-d tensors) carry gradients through every place they enter. (The tube
    # lens is not among them: the relay m_r = F / f_tube and f_obj = f_tube / M meet only as
    # f_obj m_r = F / M, so it cancels.)
    weights = torch.rand(
        len(DEPTHS), *SYSTEM.sensor_shape, generator=torch.Generator().manual_seed(5), dtype=F64
    )

    def loss(magnification: torch.Tensor, index: torch.Tensor, focal_mm: torch.Tensor) -> torch.Tensor:
        objective = ObjectiveLens(magnification, 0.12, index, 180 * mm)
        lenses = tuple(
            Lenslet(c, 0.25 * mm, focal_mm * mm if i == 2 else 5 * mm, s)
            for i, (c, s) in enumerate(zip(CENTRES, SHAPES, strict=True))
        )
        system = dataclasses.replace(SYSTEM, objective=objective, mla=MicrolensArray(lenses))
        return (weights * fourier_psf_stack(system, DEPTHS, accuracy=ACC).data / PSF_SCALE).sum()

    values = [torch.tensor(v, dtype=F64, requires_grad=True) for v in (20.0, 1.33, 5.0)]
    loss(*values).backward()
    h = 1e-6
    for i, value in enumerate(values):
        with torch.no_grad():
            up = [v.detach() + (h if j == i else 0.0) for j, v in enumerate(values)]
            down = [v.detach() - (h if j == i else 0.0) for j, v in enumerate(values)]
            numeric = float((loss(*up) - loss(*down)) / (2 * h))
        assert abs(numeric) > 1e-4
        assert float(value.grad) == pytest.approx(numeric, rel=1e-5)
