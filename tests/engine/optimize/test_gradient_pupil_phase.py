"""Gradient PSF engineering of a pupil phase mask: ``pupil_phase.zernike_waves.<noll>`` on the tiny FLFM."""

from __future__ import annotations

import dataclasses
import warnings

import pytest
import torch

from lfm_studio.engine.design import PupilPhaseSpec
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.optimize import DesignSpace, Parameter
from lfm_studio.engine.optimize.candidate import EvaluationSettings
from lfm_studio.engine.optimize.gradient import optimize_psf, psf_objective
from lfm_studio.engine.optimize.gradient_params import NotDifferentiableError, bind_space
from lfm_studio.engine.systems.fourier_psf import fourier_psf_stack
from lfm_studio.engine.systems.from_design import fourier_accuracy_of, fourier_system_of

from .conftest import tiny_flfm

SPHERICAL = DesignSpace((Parameter("pupil_phase.zernike_waves.11", -1.0, 1.0),))
F64 = EvaluationSettings(crop=None, dtype="float64")


def _masked(terms: dict[int, float]):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        return tiny_flfm().updated(pupil_phase=PupilPhaseSpec(zernike_waves=terms))


def test_a_zernike_coefficient_binds_and_matches_the_design_written_with_it():
    design = _masked({4: 0.05, 11: 0.0})
    binding = bind_space(SPHERICAL, design)
    assert [(b.field, b.noll, b.parameter.unit) for b in binding.bindings] == [("zernike_waves", 11, "waves")]
    through = binding.psf_stack(design, torch.tensor([0.2], dtype=torch.float64), F64).data
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        applied = SPHERICAL.apply(design, {"pupil_phase.zernike_waves.11": 0.2})
    assert applied.pupil_phase.zernike_waves == {4: 0.05, 11: 0.2}  # the other term is kept
    # the gradient path sums overlapping lenslets coherently (what "auto" does with gradients)
    accuracy = dataclasses.replace(
        fourier_accuracy_of(applied), method="per_lenslet_coherent", dtype=torch.float64
    )
    plain = fourier_psf_stack(fourier_system_of(applied), (-20e-6, 0.0, 20e-6), accuracy=accuracy).data
    assert float((through - plain).abs().max() / plain.max()) < 1e-9


def test_the_objective_gradient_in_a_zernike_coefficient_passes_gradcheck():
    design = _masked({11: 0.1})
    binding = bind_space(SPHERICAL, design)
    loss = psf_objective("axial_crb")

    def objective(u: torch.Tensor) -> torch.Tensor:
        return loss.loss(binding.psf_stack(design, binding.values(u), F64))

    u = binding.normalised(binding.values_of(design)).clone().requires_grad_(True)
    assert float(u.detach()[0]) == pytest.approx(0.55)
    objective(u).backward()
    assert float(u.grad[0]) != 0.0
    u.grad = None
    assert torch.autograd.gradcheck(objective, (u,), eps=1e-6, atol=1e-7, rtol=1e-4)


def test_a_short_run_engineers_a_phase_mask_and_writes_it_into_the_design():
    """From no mask (Noll 11 listed at 0), primary spherical lowers the axial bound (measured
    0.326 -> 0.280 um in 5 steps of 0.05 of the range)."""
    design = _masked({11: 0.0})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        result = optimize_psf(
            design, SPHERICAL, "axial_crb", steps=5, lr=0.05, settings=EvaluationSettings(crop=None),
            constraints=(), check_float64=False,
        )  # fmt: skip
    assert result.final_value < 0.95 * result.start_value, [h.value for h in result.history]
    coefficient = result.design.pupil_phase.zernike_waves[11]
    assert coefficient != 0.0 and -1.0 <= coefficient <= 1.0
    assert result.start_design.pupil_phase.zernike_waves == {11: 0.0}


def test_a_term_the_design_does_not_list_starts_at_zero_and_is_written_in():
    """Freeing Noll 11 on a design with no mask, or a mask without that term: it starts at 0 waves
    (the PSF of the design as it is) and the result lists it."""
    for design in (tiny_flfm(), _masked({4: 0.05})):
        binding = bind_space(SPHERICAL, design)
        assert binding.values_of(design).tolist() == [0.0]
        through = binding.psf_stack(design, torch.tensor([0.0], dtype=torch.float64), F64).data
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DesignWarning)
            listed = SPHERICAL.apply(design, {"pupil_phase.zernike_waves.11": 0.0})
        assert listed.pupil_phase.zernike_waves == {
            **(design.pupil_phase.zernike_waves if design.pupil_phase else {}),
            11: 0.0,
        }
        plain = binding.psf_stack(listed, torch.tensor([0.0], dtype=torch.float64), F64).data
        assert torch.equal(through, plain)  # an unlisted term is the listed 0.0 term
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        result = optimize_psf(
            tiny_flfm(), SPHERICAL, "axial_crb", steps=2, lr=0.05, settings=EvaluationSettings(crop=None),
            constraints=(), check_float64=False,
        )  # fmt: skip
    assert result.start_design.pupil_phase.zernike_waves == {11: 0.0}
    assert result.design.pupil_phase.zernike_waves[11] != 0.0


def test_a_bad_zernike_parameter_is_named():
    with pytest.raises(ValueError, match="zernike_waves"):
        bind_space(DesignSpace((Parameter("pupil_phase.zernike_waves.x", -1.0, 1.0),)), _masked({4: 0.0}))
    integer = DesignSpace((Parameter("pupil_phase.zernike_waves.4", 0.0, 1.0, integer=True),))
    with pytest.raises(NotDifferentiableError, match="discrete values"):
        bind_space(integer, _masked({4: 0.0}))
