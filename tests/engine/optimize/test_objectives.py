"""Objectives of kind (a): closed forms, zebrafish requirements as penalty or constraint; composition."""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.optimize import (
    Candidate,
    ClosedForm,
    EvaluationSettings,
    PSFLoss,
    RequirementsConstraint,
    RequirementsPenalty,
    WeightedSum,
    objective_named,
    objective_names,
)
from lfm_studio.engine.performance import closed_form_metrics

from .conftest import small

# The larval zebrafish spec of thesis 2.3.1, written out here (metres): independent of ZEBRAFISH_LARVA.
SPEC = {
    "field_of_view": (">=", 800e-6),
    "depth_of_field": (">=", 200e-6),
    "lateral_resolution": ("<=", 3e-6),
    "axial_resolution": ("<=", 5e-6),
}


def shortfall(metrics) -> float:
    total = 0.0
    for quantity, (comparison, limit) in SPEC.items():
        value = getattr(metrics, quantity)
        short = (limit - value) / limit if comparison == ">=" else (value - limit) / limit
        total += max(0.0, short)
    return total


@pytest.mark.parametrize("name", ["xlfm", "flfm"])
def test_requirements_penalty_is_the_relative_shortfall(name, request):
    design = request.getfixturevalue(name)
    candidate = Candidate(design, EvaluationSettings())
    metrics = closed_form_metrics(design)
    expected = shortfall(metrics)
    assert RequirementsPenalty()(candidate) == pytest.approx(expected, rel=1e-12)
    assert expected > 0  # neither preset meets every requirement (XLFM: FoV 645 um < 800 um)
    found = RequirementsConstraint().check(design)
    assert found is not None and found.reason == "requirement_failed"
    assert "field_of_view" in found.message
    only_dof = RequirementsConstraint(quantities=("depth_of_field",)).check(design)
    assert (only_dof is None) == (metrics.depth_of_field >= 200e-6)  # XLFM 440 um passes, FLFM 31 um fails
    if only_dof is not None:
        assert "depth_of_field" in only_dof.message and "field_of_view" not in only_dof.message


def test_closed_form_objectives_report_um_and_direction(flfm):
    candidate = Candidate(flfm, EvaluationSettings())
    metrics = closed_form_metrics(flfm)
    lateral = objective_named("lateral_resolution")
    assert (lateral.unit, lateral.direction) == ("um", "minimize")
    assert lateral(candidate) == pytest.approx(metrics.lateral_resolution * 1e6)
    dof = objective_named("depth_of_field")
    assert dof.direction == "maximize" and dof(candidate) == pytest.approx(metrics.depth_of_field * 1e6)
    with pytest.raises(ValueError, match="closed-form quantity"):
        ClosedForm("sharpness")
    assert {"task_ncc", "task_f1", "task_localisation", "requirements_penalty"} <= set(objective_names())


def test_weighted_sum_turns_maximised_terms_into_losses(flfm):
    candidate = Candidate(flfm, EvaluationSettings())
    lateral, dof = objective_named("lateral_resolution"), objective_named("depth_of_field")
    total = WeightedSum(((lateral, 2.0), (dof, 0.5)))
    assert total.direction == "minimize"
    assert total(candidate) == pytest.approx(2.0 * lateral(candidate) - 0.5 * dof(candidate))


def test_psf_loss_hook_and_measured_requirements():
    """A PSF loss sees the candidate's stack; the measured penalty is computed from that stack."""
    design = small("flfm_guo2019", 200, (-20.0, 20.0), 20.0)
    candidate = Candidate(design, EvaluationSettings(crop=None))
    seen = []

    def peak(stack) -> torch.Tensor:
        seen.append(tuple(stack.data.shape))
        return stack.data.amax()

    value = PSFLoss("peak", peak)(candidate)
    assert seen == [(3, 200, 200)] and value == pytest.approx(float(candidate.stack.data.max()))
    measured = RequirementsPenalty(basis="measured")
    assert measured.name == "measured_requirements_penalty"
    assert measured(candidate) >= 0.0
    assert len(seen) == 1 and "psf_s" in candidate.timing  # the stack was computed once


def test_score_options_name_what_changes_a_score():
    """Stored with a study (a resume must repeat them): photons/background of axial_crb, the task settings."""
    from lfm_studio.engine.optimize import objective_named
    from lfm_studio.engine.optimize.objectives import CRB_PHOTONS, score_options

    assert score_options(objective_named("axial_crb")) == {"photons": CRB_PHOTONS, "background": 1.0}
    assert score_options(objective_named("axial_crb", {"photons": None, "background": 50})) == {
        "photons": 1000.0,
        "background": 50.0,
    }
    task = score_options(objective_named("task_ncc", {"iterations": 2, "seeds": (5, 6), "photons": None}))
    assert task["iterations"] == 2 and task["seeds"] == [5, 6] and task["photons"] == 1e5
    assert score_options(objective_named("lateral_resolution")) == {}
