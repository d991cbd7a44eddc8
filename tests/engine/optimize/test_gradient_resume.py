"""The design a gradient run returns (the best point, or the last on request) and resuming a stored run."""

from __future__ import annotations

import warnings

import pytest

from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.optimize.gradient import optimize_psf
from lfm_studio.engine.optimize.study import load_study, record_of
from lfm_studio.engine.progress import CancelledError

from .conftest import tiny_flfm
from .test_gradient_psf import SETTINGS, SPACE

pytest.importorskip("optuna")


@pytest.fixture(scope="module")
def poor_start():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        return SPACE.apply(
            tiny_flfm(), {"mla.lenslets[*].focal_length_mm": 22.0, "mla_to_camera_distance_mm": 15.0}
        )


def _run(design, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        return optimize_psf(
            design, SPACE, "axial_crb", settings=SETTINGS, constraints=(), check_float64=False, **kwargs
        )


def _values(design):
    return {k: float(v) for k, v in SPACE.values_of(design).items()}


def test_the_best_point_is_returned_not_the_last_unless_asked(poor_start, tmp_path):
    """lr 0.3 overshoots: measured 1.51, 0.287 (step 1), 0.386, 0.86, 0.403 um, last point 0.377 um."""
    best = _run(poor_start, steps=5, lr=0.3, study=str(tmp_path / "s.db"))
    assert best.final == "best" and best.best is not None and best.best.step == 1
    assert best.last_value > best.best.value  # the overshoot: the last point is worse
    assert best.final_value == pytest.approx(best.best.value)
    assert _values(best.design) == pytest.approx(best.best.point)
    # the last point is stored too (a trial flagged last), and the summary names both
    study = load_study(str(tmp_path / "s.db"))
    last = study.trials[-1]
    assert record_of(last)["gradient"]["last"] is True and last.values[0] == pytest.approx(best.last_value)
    assert study.user_attrs["gradient"]["final"] == "best"
    assert study.user_attrs["gradient"]["last_point"] == pytest.approx(best.last_point)
    kept = _run(poor_start, steps=5, lr=0.3, final="last")
    assert kept.final_value == pytest.approx(kept.last_value)
    assert _values(kept.design) == pytest.approx(kept.last_point)
    with pytest.raises(ValueError, match="final must be one of"):
        _run(poor_start, steps=1, final="first")


def test_resume_continues_the_step_numbers_from_the_stored_last_point(poor_start, tmp_path):
    db = str(tmp_path / "r.db")
    first = _run(poor_start, steps=3, lr=0.1, study=db, final="last")
    with pytest.raises(ValueError, match="already exists"):
        _run(poor_start, steps=5, lr=0.1, study=db)
    with pytest.raises(ValueError, match="leaves nothing to resume"):
        _run(poor_start, steps=3, lr=0.1, study=db, resume=True, final="last")
    resumed = _run(poor_start, steps=5, lr=0.1, study=db, resume=True, final="last")
    assert resumed.resumed_from == 3 and [h.step for h in resumed.history] == [0, 1, 2, 3, 4]
    assert [h.value for h in resumed.history[:3]] == pytest.approx([h.value for h in first.history])
    # Adam restarts at the stored last point: step 3 evaluates it
    assert resumed.history[3].point == pytest.approx(first.last_point)
    assert resumed.history[3].value == pytest.approx(first.last_value, rel=1e-6)
    study = load_study(db)
    steps = [record_of(t)["gradient"] for t in study.trials]
    assert [g["step"] for g in steps if not g.get("last")] == [0, 1, 2, 3, 4]  # none recorded twice
    assert [g["step"] for g in steps if g.get("last")] == [3, 5]
    assert resumed.history[-1].value < resumed.history[0].value


def test_a_killed_run_resumes_at_the_next_step_from_the_best_stored_point(poor_start, tmp_path):
    db = str(tmp_path / "k.db")
    calls = []

    def cancel() -> bool:  # stops before step 2 (checkpoints: step 0, step 1, step 2)
        calls.append(1)
        return len(calls) > 2

    with pytest.raises(CancelledError):
        _run(poor_start, steps=4, lr=0.1, study=db, cancel=cancel)
    study = load_study(db)
    stored = [record_of(t)["gradient"] for t in study.trials]
    assert [g["step"] for g in stored] == [0, 1] and not any(g.get("last") for g in stored)
    best_stored = min(study.trials, key=lambda t: t.values[0])
    resumed = _run(poor_start, steps=4, lr=0.1, study=db, resume=True)
    assert resumed.resumed_from == 2 and [h.step for h in resumed.history] == [0, 1, 2, 3]
    assert resumed.history[2].point == pytest.approx(best_stored.params)
    assert resumed.final_value <= min(h.value for h in resumed.history) + 1e-12
