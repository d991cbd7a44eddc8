"""Gradient PSF engineering of a conventional LFM (tiny 10x/0.3 design, 3 x 3 lenslets, 3 depths).

The pattern stack holds one PSF per voxel sub-position; the PSF losses average over them.
"""

from __future__ import annotations

import warnings

import pytest
import torch

from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.optimize import DesignSpace, Parameter
from lfm_studio.engine.optimize.candidate import EvaluationSettings
from lfm_studio.engine.optimize.gradient import optimize_psf, psf_objective
from lfm_studio.engine.optimize.gradient_params import NotDifferentiableError, bind_space
from lfm_studio.engine.simulation import simulate_psf
from lfm_studio.engine.systems.kinds import CONVENTIONAL

from .conftest import tiny_conventional

ALL = DesignSpace(
    (
        Parameter("mla.focal_length_mm", 1.5, 2.5),
        Parameter("mla_to_camera_distance_mm", 1.5, 2.5),
        Parameter("objective.numerical_aperture", 0.2, 0.4),
        Parameter("wavelength_nm", 450.0, 650.0),
        Parameter("mla.lenslet_aperture_diameter_um", 100.0, 125.0),
    )
)
F64 = EvaluationSettings(crop=None, dtype="float64")


@pytest.fixture(scope="module")
def design():
    """The tiny conventional LFM with a 110 um clear aperture (away from the kink at the pitch)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        return ALL.apply(tiny_conventional(), {"mla.lenslet_aperture_diameter_um": 110.0})


def test_every_conventional_parameter_binds_and_the_stack_equals_the_float_path(design):
    binding = bind_space(ALL, design)
    assert binding.kind is CONVENTIONAL
    assert [b.field for b in binding.bindings] == [
        "lenslet_focal_length", "mla_to_camera", "numerical_aperture", "wavelength", "lenslet_aperture",
    ]  # fmt: skip
    point = {
        "mla.focal_length_mm": 1.9,
        "mla_to_camera_distance_mm": 1.8,
        "objective.numerical_aperture": 0.28,
        "wavelength_nm": 560.0,
        "mla.lenslet_aperture_diameter_um": 115.0,
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        applied = ALL.apply(design, point)
    through = binding.psf_stack(design, torch.tensor(list(point.values()), dtype=torch.float64), F64)
    plain = simulate_psf(applied, dtype="float64")
    assert through.data.shape == plain.data.shape and through.data.ndim == 5  # (S, S, Z, H, H)
    assert float((through.data - plain.data).abs().max() / plain.data.abs().max()) < 1e-9


def test_the_objective_gradient_passes_gradcheck(design):
    binding = bind_space(ALL, design)
    loss = psf_objective("axial_crb")

    def objective(u: torch.Tensor) -> torch.Tensor:
        return loss.loss(binding.psf_stack(design, binding.values(u), F64))

    u = binding.normalised(binding.values_of(design)).clone().requires_grad_(True)
    objective(u).backward()
    assert int((u.grad != 0).sum()) == 5, u.grad  # every parameter moves the bound
    # gradcheck on two of them (focal length, NA) keeps the test short
    pair = DesignSpace(ALL.parameters[:1] + ALL.parameters[2:3])
    two = bind_space(pair, design)

    def pair_objective(v: torch.Tensor) -> torch.Tensor:
        return loss.loss(two.psf_stack(design, two.values(v), F64))

    v = two.normalised(two.values_of(design)).clone().requires_grad_(True)
    assert torch.autograd.gradcheck(pair_objective, (v,), eps=1e-6, atol=1e-7, rtol=1e-4)


def test_a_short_run_lowers_the_axial_crb(design):
    """Focal length and NA freed: measured 0.73 -> 0.51 um in 5 Adam steps of 0.1 of the range."""
    space = DesignSpace((ALL.parameters[0], ALL.parameters[2]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        result = optimize_psf(
            design, space, "axial_crb", steps=5, lr=0.1, settings=EvaluationSettings(crop=None),
            constraints=(), check_float64=False,
        )  # fmt: skip
    values = [h.value for h in result.history]
    assert result.final_value < 0.9 * result.start_value, values
    final = space.values_of(result.design)
    assert final["mla.focal_length_mm"] != design.mla.focal_length_mm
    for param in space.parameters:
        assert param.low <= final[param.path] <= param.high


def test_other_conventional_paths_are_refused_with_the_conventional_list(design):
    with pytest.raises(
        NotDifferentiableError, match=r"Differentiable paths: objective\.numerical_aperture, mla_to"
    ):
        bind_space(DesignSpace((Parameter("mla.pitch_um", 100.0, 150.0),)), design)


def test_end_to_end_trains_a_conventional_design_with_its_lattice_projector(design):
    """Focal length and NA with a learned unrolled RL, 4 steps: measured held-out 0.83 -> 0.58."""
    from lfm_studio.engine.optimize.end_to_end import optimize_end_to_end

    space = DesignSpace((ALL.parameters[0], ALL.parameters[2]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        result = optimize_end_to_end(
            tiny_conventional(), space, steps=4, lr=0.1, settings=EvaluationSettings(crop=None),
            constraints=(), batch=2, held_out=3, iterations=4,
        )  # fmt: skip
    extra = result.extra
    assert extra["held_out_final"] < 0.9 * extra["held_out_start"], extra
    assert extra["final_volume_trivial"] is None
    assert result.check is not None and result.check.relative_error < 1e-3
