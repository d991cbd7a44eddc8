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


def test_shift_variant_stacks_average_the_source_positions():
    """A conventional LFM stack holds one (Z, Y, X) stack per source position: the loss is their mean."""
    from types import SimpleNamespace

    from lfm_studio.engine.optimize.objectives import AxialCRBLoss, DepthDissimilarityLoss, MTFSupportLoss

    gen = torch.Generator().manual_seed(3)
    data = torch.rand((2, 3, 4, 16, 16), generator=gen, dtype=torch.float64)
    depths = (-10e-6, 0.0, 10e-6, 25e-6)
    stack = SimpleNamespace(data=data, depths=depths)
    flat = data.reshape(6, 4, 16, 16)
    z = torch.tensor(depths, dtype=torch.float64)
    crb = torch.stack([axial_crb(p, z, photons=1000.0, background=1.0).mean() for p in flat]).mean() * 1e6
    assert float(AxialCRBLoss()(stack)) == pytest.approx(float(crb), rel=1e-12)
    dis = torch.stack([depth_dissimilarity(p) for p in flat]).mean()
    assert float(DepthDissimilarityLoss()(stack)) == pytest.approx(float(dis), rel=1e-12)
    sup = torch.stack([mtf_support(p).mean() for p in flat]).mean()
    assert float(MTFSupportLoss()(stack)) == pytest.approx(float(sup), rel=1e-12)
