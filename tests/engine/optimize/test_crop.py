"""The PSF crop of a study: how many sub-image centres it holds, the automatic crop, and the
task score's all-zero floor on a crop that holds none (xlfm_cong2017 at the old default 256 px)."""

from __future__ import annotations

import json
import math

import pytest

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.design.space import space_from_json
from lfm_studio.engine.optimize import (
    Candidate,
    EvaluationSettings,
    Evaluator,
    TaskFloorWarning,
    TaskScore,
    auto_crop,
    crop_views,
)
from lfm_studio.engine.simulation import simulate_psf


def _radii_px(design):
    return sorted(math.hypot(*lens.center_um) / design.camera.pixel_pitch_um for lens in design.mla.lenslets)


def test_views_on_a_crop_follow_the_lenslet_centres(xlfm):
    # Independent count: a square crop of side c px about the axis holds a centre when |x|, |y| < c / 2 px.
    def by_hand(crop):
        half_um = crop / 2 * xlfm.camera.pixel_pitch_um
        return sum(max(abs(c) for c in lens.center_um) < half_um for lens in xlfm.mla.lenslets)

    assert _radii_px(xlfm)[:3] == pytest.approx([195.4] * 3, abs=0.1)  # the innermost shell
    for crop in (128, 256, 384, 512, 1024):
        assert crop_views(xlfm, crop).views == by_hand(crop)
    assert [crop_views(xlfm, c).views for c in (256, 384, 512)] == [0, 2, 3]
    assert crop_views(xlfm, None).views == 27 and crop_views(xlfm, 256).needed == 3
    assert not crop_views(xlfm, 256).enough and crop_views(xlfm, 512).enough
    assert auto_crop(xlfm) == 512
    flfm = load_preset("flfm_guo2019")
    assert crop_views(flfm, 256).views == 9 and auto_crop(flfm) == 256  # as before: the old default
    conventional = load_preset("lfm_10x_na03")
    assert crop_views(conventional, 256) is None and auto_crop(conventional) == 256


def test_the_automatic_crop_holds_the_light_the_old_default_lost(xlfm):
    """The simulated on-axis PSF: 256 px keeps its diffraction tails only, the automatic crop a
    tenth of the light (three of 27 views)."""
    full = simulate_psf(xlfm, depths=(0.0,)).data[0]
    total = float(full.sum())
    fractions = {
        crop: float(simulate_psf(xlfm, depths=(0.0,), crop=crop).data.sum()) / total for crop in (256, 512)
    }
    assert fractions[256] < 1e-3
    assert fractions[512] > 0.08  # measured 0.102 (3 / 27 = 0.111 of the lenslets)


@pytest.fixture(scope="module")
def one_point():
    return space_from_json(json.dumps({"parameters": [{"path": "relay.focal_length_mm", "choices": [160]}]}))


def test_a_task_score_at_the_floor_is_flagged_in_the_record(xlfm, one_point):
    """XLFM, 3 depths: at 256 px (no view on the crop) task_ncc is near the all-zero volume's 0 and the
    record says so; at the automatic 512 px it is well above and nothing is flagged."""
    score = TaskScore("ncc", iterations=10, seeds=(1000,))
    records = {}
    for crop in (256, 512):
        evaluator = Evaluator(xlfm, one_point, [score], settings=EvaluationSettings(crop=crop))
        records[crop] = evaluator({"relay.focal_length_mm": 160})
    low, high = records[256], records[512]
    assert low.values["task_ncc"] < 0.05 < 0.3 < high.values["task_ncc"]
    assert low.at_floor == ("task_ncc",) and low.attrs()["at_floor"] == ["task_ncc"]
    assert any("does not beat the all-zero volume" in note for note in low.warnings)
    assert high.at_floor == () and not any("all-zero" in note for note in high.warnings)


def test_the_floor_is_the_all_zero_score_and_the_margin_is_checked(xlfm):
    candidate = Candidate(xlfm, EvaluationSettings(crop=256))
    ncc = TaskScore("ncc", iterations=5, seeds=(1000,))
    with pytest.warns(TaskFloorWarning, match="task_ncc .* does not beat the all-zero volume's 0") as caught:
        value = ncc(candidate)
    warning = caught[0].message
    assert (warning.objective, warning.value, warning.floor, warning.threshold) == (
        "task_ncc",
        value,
        0.0,
        0.05,
    )
    # The localisation floor is the worst error: the tolerance (2 voxels) along the coarsest axis (20 um depths).
    localisation = TaskScore("localisation", iterations=5, seeds=(1000,))
    assert localisation.floor(candidate) == pytest.approx(2 * max(candidate.setup.voxel_size) * 1e6) == 40.0
    assert localisation.threshold(40.0) == pytest.approx(38.0)  # 5 % of the way to 0 um
    assert TaskScore("ncc", margin=0.0).threshold(0.0) == 0.0 and TaskScore("f1").threshold(0.0) == 0.05
    with pytest.raises(ValueError, match=r"margin must lie in \[0, 1\).*got 1.5.*Fix: e.g. 0.05"):
        TaskScore(margin=1.5)


def test_a_study_without_settings_takes_the_designs_automatic_crop(xlfm):
    # The Python API as the CLI and the studio: no settings given -> the crop that holds enough views.
    from lfm_studio.engine.design.space import DesignSpace, Parameter
    from lfm_studio.engine.optimize import objective_named

    space = DesignSpace((Parameter("relay.focal_length_mm", 150.0, 170.0, points=2),))
    views = [objective_named("number_of_views")]
    assert Evaluator(xlfm, space, views, constraints=()).settings.crop == 512
    flfm = load_preset("flfm_guo2019")
    assert Evaluator(flfm, space, views, constraints=()).settings.crop == 256 == auto_crop(flfm)
    assert EvaluationSettings().crop == 256  # explicit settings keep their own default
    given = EvaluationSettings(crop=384)
    assert Evaluator(xlfm, space, views, settings=given, constraints=()).settings is given


def test_a_resumed_study_keeps_its_stored_crop_and_a_mismatch_names_it(xlfm, tmp_path):
    # A study stored with the old default crop (256 px) resumes with it (stored_crop, as the CLI and the
    # studio do); resumed with the automatic crop instead, the refusal names the crop's two values.
    pytest.importorskip("optuna")
    from lfm_studio.engine.design.space import DesignSpace, Parameter
    from lfm_studio.engine.optimize import objective_named
    from lfm_studio.engine.optimize.study import StudyMismatchError, run_study, stored_crop

    space = DesignSpace((Parameter("relay.focal_length_mm", 150.0, 170.0, points=2),))
    views = [objective_named("number_of_views")]
    storage = str(tmp_path / "old.db")
    assert stored_crop(storage) == (False, None)  # no database yet
    run_study(
        Evaluator(xlfm, space, views, settings=EvaluationSettings(), constraints=()), storage, n_trials=1
    )
    assert stored_crop(storage) == (True, 256)
    automatic = Evaluator(xlfm, space, views, constraints=())  # crop 512
    with pytest.raises(StudyMismatchError, match=r"other settings \(crop: stored 256, now 512\)"):
        run_study(automatic, storage, n_trials=1, resume=True)
    kept = Evaluator(
        xlfm, space, views, settings=EvaluationSettings(crop=stored_crop(storage)[1]), constraints=()
    )
    assert (
        len(run_study(kept, storage, n_trials=2, resume=True).trials) == 2
    )  # the budget counts stored trials
