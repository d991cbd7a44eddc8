"""A parameter the objective cannot see: the NA of a Fourier design whose lenslets all lie inside the
relayed pupil (xlfm_cong2017), checked on the PSFs themselves and reported from a study."""

from __future__ import annotations

import json

import pytest
import torch

from lfm_studio.engine.design.space import space_from_json
from lfm_studio.engine.optimize import Evaluator, InsidePupil, objective_named
from lfm_studio.engine.simulation import simulate_psf

pytest.importorskip("optuna")


def _with(design, na, relay_mm):
    return design.updated(
        objective=design.objective.model_copy(update={"numerical_aperture": na}),
        relay=design.relay.model_copy(update={"focal_length_mm": relay_mm}),
    )


@pytest.mark.filterwarnings(
    "ignore::lfm_studio.engine.design.errors.DesignWarning"
)  # 140 mm: sub-images overlap
def test_the_na_changes_an_xlfm_psf_only_when_the_pupil_cuts_a_lenslet(xlfm):
    """No cache: the per-lenslet and the full-field paths give the same PSF for NA 0.8 and 1.0
    (relayed pupil radius 6.4 / 8.0 mm, lenslets out to 6.04 mm); with a 140 mm relay the NA 0.8
    pupil (5.6 mm) cuts the outer lenslets, the PSF changes, and InsidePupil refuses the design."""
    depths = (-20e-6, 20e-6)
    reach = max(lens.reach_um for lens in xlfm.mla.lenslets)
    assert reach == pytest.approx(6037.0, abs=1.0)
    psfs = {}
    for na, relay in ((1.0, 160.0), (0.8, 160.0), (1.0, 140.0), (0.8, 140.0)):
        design = _with(xlfm, na, relay)
        psfs[na, relay] = simulate_psf(design, depths=depths, cache=None).data  # whole sensor
        inside = design.pupil_diameter_at_mla / 2 * 1e6 >= reach
        assert (InsidePupil().check(design) is None) == inside == ((na, relay) != (0.8, 140.0))
    assert float(psfs[1.0, 160.0].sum()) > 0
    assert torch.equal(psfs[0.8, 160.0], psfs[1.0, 160.0])
    change = (psfs[0.8, 140.0] - psfs[1.0, 140.0]).abs().max() / psfs[1.0, 140.0].max()
    assert change > 0.1  # the NA is applied: where the pupil cuts a lenslet it changes the PSF
    full_field = [
        simulate_psf(
            _with(xlfm, na, 160.0).updated(
                accuracy=xlfm.accuracy.model_copy(update={"per_lenslet": False, "preset": "custom"})
            ),
            depths=(0.0,),
            crop=512,
        ).data
        for na in (1.0, 0.8)
    ]
    assert float(full_field[0].sum()) > 0 and torch.equal(full_field[0], full_field[1])


def test_a_study_reports_the_parameters_its_objectives_do_not_see(tmp_path, xlfm):
    """NA x relay on the XLFM, closed forms: no objective sees the NA, the view count sees neither,
    the lateral resolution sees the relay (its effective NA is the lenslet's, d / (2 f_obj m_r))."""
    from lfm_studio.engine.optimize.study import run_study
    from lfm_studio.engine.optimize.study_report import insensitive_parameters

    space = space_from_json(
        json.dumps(
            {
                "parameters": [
                    {"path": "objective.numerical_aperture", "choices": [0.8, 0.9, 1.0]},
                    {"path": "relay.focal_length_mm", "choices": [160, 180]},
                ]
            }
        )
    )
    names = ("lateral_resolution", "number_of_views")
    evaluator = Evaluator(xlfm, space, [objective_named(n) for n in names])
    study = run_study(evaluator, f"sqlite:///{tmp_path / 's.db'}")
    values = {tuple(t.params.values()): tuple(t.values) for t in study.trials}
    assert len(values) == 6 and values[0.8, 160] == values[1.0, 160] != values[1.0, 180]
    found = {(f.parameter, f.objective): f.groups for f in insensitive_parameters(study)}
    assert found == {
        ("objective.numerical_aperture", "lateral_resolution"): 2,
        ("objective.numerical_aperture", "number_of_views"): 2,
        ("relay.focal_length_mm", "number_of_views"): 3,
    }
