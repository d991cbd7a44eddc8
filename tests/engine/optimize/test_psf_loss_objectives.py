"""The section 5.2.2 PSF losses as named objectives, checked against the loss functions called directly."""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.optimize import Candidate, EvaluationSettings, objective_named, objective_names
from lfm_studio.engine.optimize.psf_losses import axial_crb, depth_dissimilarity, mtf_support

from .conftest import small


@pytest.fixture(scope="module")
def candidate():
    design = small("flfm_guo2019", 200, (-20.0, 20.0), 20.0)
    return Candidate(design, EvaluationSettings(crop=None))


def test_psf_loss_objectives_are_registered_with_unit_and_direction():
    names = objective_names()
    expected = {
        "axial_crb": ("um", "minimize"),
        "depth_dissimilarity": ("", "minimize"),
        "mtf_support": ("", "maximize"),
    }
    for name, (unit, direction) in expected.items():
        assert name in names
        objective = objective_named(name)
        assert (objective.name, objective.unit, objective.direction) == (name, unit, direction)


def test_psf_loss_objectives_match_the_loss_functions(candidate):
    psf = candidate.stack.data.to(torch.float64)
    depths = torch.tensor(candidate.stack.depths, dtype=torch.float64)
    assert psf.shape[0] == 3
    crb_um = float(axial_crb(psf, depths, photons=500.0, background=2.0).mean()) * 1e6
    got = objective_named("axial_crb", {"photons": 500.0, "background": 2.0})(candidate)
    assert got == pytest.approx(crb_um, rel=1e-4)
    assert 0.01 < got < 1e4  # a finite bound in micrometres, not metres
    assert objective_named("depth_dissimilarity")(candidate) == pytest.approx(
        float(depth_dissimilarity(psf, reduction="mean")), rel=1e-4
    )
    assert objective_named("mtf_support")(candidate) == pytest.approx(
        float(mtf_support(psf).mean()), abs=1e-6
    )
    assert "psf_loss_s" in candidate.timing


def test_axial_crb_objective_scales_with_photons(candidate):
    """Without background the bound falls as 1/sqrt(photons): a closed-form scaling, not a fixed number."""
    low = objective_named("axial_crb", {"photons": 100.0, "background": 0.0})(candidate)
    high = objective_named("axial_crb", {"photons": 10000.0, "background": 0.0})(candidate)
    assert low / high == pytest.approx(10.0, rel=1e-3)
