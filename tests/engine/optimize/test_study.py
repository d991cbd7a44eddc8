"""Stored studies: every candidate recorded; a killed run resumes to the uninterrupted result and
never evaluates a stored candidate again; samplers; Pareto front; Dask evaluation."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import pytest

from lfm_studio.engine.design.design_io import design_from_json
from lfm_studio.engine.optimize import ClosedForm, DesignSpace, Evaluator, Parameter
from lfm_studio.engine.optimize.study import StudyMismatchError, load_study, record_of, run_study
from lfm_studio.engine.optimize.study_report import format_front, format_table, pareto_front, summary

pytest.importorskip("optuna")

# 4 x 3 = 12 points; moving lenslet 4 by +-20 um makes it overlap a neighbour (its aperture, or
# for small apertures its sub-image): infeasible.
SPACE = DesignSpace(
    (
        Parameter("mla.lenslets[*].aperture_diameter_um", 450, 600, step=50),
        Parameter("mla.lenslets[4].center_um[0]", -20, 20, step=20),
    )
)


@dataclass
class Counting:
    """A closed-form objective that counts its calls (and can stop the process on call ``stop_at``)."""

    inner: ClosedForm = field(
        default_factory=lambda: ClosedForm("effective_numerical_aperture", "maximize", "")
    )
    calls: int = 0
    stop_at: int | None = None
    stop_with: type[BaseException] = field(default_factory=lambda: Killed)

    name: str = "effective_numerical_aperture"
    unit: str = ""
    direction: str = "maximize"

    def __call__(self, candidate) -> float:
        self.calls += 1
        if self.stop_at is not None and self.calls == self.stop_at:
            raise self.stop_with("process killed while evaluating")
        return self.inner(candidate)


class Killed(BaseException):
    """Stands for SIGKILL: not an Exception, nothing catches it."""


def _result(study) -> dict:
    """Point -> (state, values, reason) of every trial with a result (interrupted ones left out)."""
    out = {}
    for t in study.get_trials(deepcopy=False):
        reason = record_of(t).get("infeasible_reason")
        if t.state.name == "COMPLETE" or reason is not None:
            key = json.dumps(t.params, sort_keys=True)
            out[key] = (t.state.name, None if t.state.name != "COMPLETE" else tuple(t.values), reason)
    return out


@pytest.fixture
def uninterrupted(flfm, tmp_path):
    objective = Counting()
    study = run_study(Evaluator(flfm, SPACE, [objective]), f"sqlite:///{tmp_path / 'a.db'}")
    return study, objective


def test_every_candidate_is_stored_with_its_record(uninterrupted, flfm):
    study, objective = uninterrupted
    trials = study.get_trials(deepcopy=False)
    assert len(trials) == SPACE.grid_size() == 12
    assert objective.calls == 4  # only the centred lenslet 4 is feasible, for each aperture
    assert study.user_attrs["objectives"] == [
        {"name": "effective_numerical_aperture", "unit": "", "direction": "maximize"}
    ]
    assert study.user_attrs["space"] == SPACE.to_dict()
    for t in trials:
        attrs = record_of(t)
        assert attrs["seed"] == 0 and "total_s" in attrs["timing"]
        if t.state.name == "COMPLETE":
            design = design_from_json(attrs["design_json"])
            assert (
                design.mla.lenslets[0].aperture_diameter_um
                == t.params["mla.lenslets[*].aperture_diameter_um"]
            )
            assert attrs["values"] == {"effective_numerical_aperture": t.values[0]}
            assert attrs["infeasible_reason"] is None
        else:
            assert t.state.name == "FAIL"
            assert (
                attrs["infeasible_reason"] in ("lenslet_overlap", "sub_image_overlap")
                and "overlap" in attrs["infeasible_message"]
            )
            assert attrs["design_json"] is None
    best = pareto_front(study)[0]
    assert best.params == {"mla.lenslets[*].aperture_diameter_um": 600.0, "mla.lenslets[4].center_um[0]": 0.0}


def test_killed_in_a_callback_then_resumed_equals_uninterrupted(uninterrupted, flfm, tmp_path):
    reference, _ = uninterrupted
    objective = Counting()
    evaluator = Evaluator(flfm, SPACE, [objective])
    url = f"sqlite:///{tmp_path / 'b.db'}"

    def kill_after_five(study, trial, record):
        if trial.number == 4:
            raise Killed("killed after 5 stored candidates")

    with pytest.raises(Killed):
        run_study(evaluator, url, callbacks=[kill_after_five])
    assert len(load_study(url).get_trials(deepcopy=False)) == 5
    calls_before = objective.calls
    seen = []
    resumed = run_study(evaluator, url, resume=True, callbacks=[lambda s, t, r: seen.append(t.number)])
    assert _result(resumed) == _result(reference)
    assert seen == list(range(5, 12))  # only the 7 points without a stored result
    assert objective.calls == 4 and calls_before == 2  # every feasible point evaluated exactly once
    # A third run finds nothing to do.
    run_study(evaluator, url, resume=True)
    assert objective.calls == 4 and len(load_study(url).get_trials()) == 12


def test_killed_while_evaluating_then_resumed(uninterrupted, flfm, tmp_path):
    reference, _ = uninterrupted
    objective = Counting(stop_at=3)  # dies inside the 3rd evaluation: that trial stays RUNNING
    evaluator = Evaluator(flfm, SPACE, [objective])
    url = f"sqlite:///{tmp_path / 'c.db'}"
    with pytest.raises(Killed):
        run_study(evaluator, url)
    assert [t.state.name for t in load_study(url).get_trials()].count("RUNNING") == 1
    objective.stop_at = None
    resumed = run_study(evaluator, url, resume=True)
    assert _result(resumed) == _result(reference)
    assert summary(resumed)["interrupted"] == 1  # kept for the record, without a result
    assert objective.calls == 5  # 2 before, the interrupted one again, 2 more


def test_ctrl_c_while_evaluating_marks_the_trial_interrupted_not_running(uninterrupted, flfm, tmp_path):
    reference, _ = uninterrupted
    objective = Counting(stop_at=3, stop_with=KeyboardInterrupt)  # Ctrl+C in the 3rd evaluation
    evaluator = Evaluator(flfm, SPACE, [objective])
    url = f"sqlite:///{tmp_path / 'i.db'}"
    with pytest.raises(KeyboardInterrupt):
        run_study(evaluator, url)
    stored = load_study(url)
    assert [t.state.name for t in stored.get_trials()].count("RUNNING") == 0  # `study show`: not running
    assert summary(stored)["interrupted"] == 1  # the only one without a result; the others are kept
    assert len(_result(stored)) == len(stored.get_trials()) - 1
    objective.stop_at = None
    resumed = run_study(evaluator, url, resume=True)
    assert _result(resumed) == _result(reference) and objective.calls == 5  # the interrupted point again


def test_existing_study_needs_resume_and_the_same_search(uninterrupted, flfm, tmp_path):
    url = f"sqlite:///{tmp_path / 'a.db'}"
    with pytest.raises(ValueError, match=r"already exists.*--resume"):
        run_study(Evaluator(flfm, SPACE, [Counting()]), url)
    other = DesignSpace((Parameter("mla.lenslets[*].aperture_diameter_um", 450, 600, step=75),))
    with pytest.raises(StudyMismatchError, match="another space"):
        run_study(Evaluator(flfm, other, [Counting()]), url, resume=True)


def test_a_sampler_never_evaluates_a_stored_point_twice(flfm, tmp_path):
    space = DesignSpace((Parameter("mla.lenslets[*].aperture_diameter_um", choices=(500.0, 600.0)),))
    objective = Counting()
    study = run_study(
        Evaluator(flfm, space, [objective]), f"sqlite:///{tmp_path / 't.db'}", sampler="tpe", n_trials=8
    )
    trials = study.get_trials(deepcopy=False)
    assert len(trials) == 8
    evaluated = [t for t in trials if "reused_from" not in record_of(t)]
    assert objective.calls == len(evaluated) <= 2
    for t in trials:
        if "reused_from" in record_of(t):
            source = trials[record_of(t)["reused_from"]]
            assert source.params == t.params and source.values == t.values
    with pytest.raises(ValueError, match="sampler must be one of"):
        run_study(Evaluator(flfm, space, [objective]), f"sqlite:///{tmp_path / 'u.db'}", sampler="bayes")


def test_pareto_front_of_two_objectives(flfm, tmp_path):
    """Larger apertures: better NA_eff, shorter depth of field. Every feasible aperture is on the
    front (checked by brute-force dominance here), and the table names the infeasible reasons."""
    space = DesignSpace((Parameter("mla.lenslets[*].aperture_diameter_um", 400, 700, step=100),))
    objectives = [
        ClosedForm("effective_numerical_aperture", "maximize", ""),
        ClosedForm("depth_of_field", "maximize"),
    ]
    study = run_study(Evaluator(flfm, space, objectives), f"sqlite:///{tmp_path / 'p.db'}")
    done = [t for t in study.get_trials() if t.state.name == "COMPLETE"]

    def dominated(a, b):  # b dominates a (both maximised)
        return all(y >= x for x, y in zip(a.values, b.values, strict=True)) and a.values != b.values

    expected = sorted(t.number for t in done if not any(dominated(t, o) for o in done))
    assert sorted(t.number for t in pareto_front(study)) == expected == [0, 1, 2]
    table = format_table(study)
    assert "lenslet_overlap" in table and "effective_numerical_aperture [-] (max)" in table
    assert "depth_of_field [um] (max)" in table
    assert format_front(study).startswith("Pareto front (3 candidates)")


def test_dask_client_gives_the_in_process_result(uninterrupted, flfm, tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    reference, _ = uninterrupted
    with distributed.Client(
        processes=False, n_workers=2, threads_per_worker=1, dashboard_address=None
    ) as client:
        study = run_study(
            Evaluator(flfm, SPACE, [Counting()]), f"sqlite:///{tmp_path / 'd.db'}", client=client
        )
    assert _result(study) == _result(reference)


@dataclass(frozen=True)
class Photons:
    """A cheap objective with a score option: the closed-form NA times ``photons``."""

    photons: float = 1000.0
    name: str = "scaled_na"
    unit: str = ""
    direction: str = "maximize"

    def score_options(self) -> dict:
        return {"photons": self.photons}

    def __call__(self, candidate) -> float:
        return self.photons * ClosedForm("effective_numerical_aperture", "maximize", "")(candidate)


ONE_POINT = DesignSpace((Parameter("mla.lenslets[*].aperture_diameter_um", choices=(500.0, 550.0)),))


def test_a_resume_with_other_objective_options_is_refused_naming_each(flfm, tmp_path):
    """walk4 #2: a resume with another --photons mixed two settings' scores in one ranking."""
    url = f"sqlite:///{tmp_path / 'p.db'}"
    run_study(Evaluator(flfm, ONE_POINT, [Photons(1e5)]), url, n_trials=1)
    assert load_study(url).user_attrs["objective_options"] == {"scaled_na": {"photons": 1e5}}
    with pytest.raises(
        StudyMismatchError,
        match=r"other objective options \(scaled_na photons: stored 100000.0, now 1000.0\).*Fix",
    ):
        run_study(Evaluator(flfm, ONE_POINT, [Photons(1000.0)]), url, resume=True)
    assert len(load_study(url).get_trials()) == 1  # nothing scored with the other options
    resumed = run_study(Evaluator(flfm, ONE_POINT, [Photons(1e5)]), url, resume=True)
    assert len(resumed.get_trials()) == 2


def test_a_study_stored_without_options_resumes_with_a_warning(flfm, tmp_path):
    from lfm_studio.engine.optimize.study import StudyOptionsUncheckedWarning, open_stored, study_attrs

    url = f"sqlite:///{tmp_path / 'old.db'}"
    evaluator = Evaluator(flfm, ONE_POINT, [Photons(1e5)])
    old = study_attrs(evaluator, "grid")
    del old["objective_options"]  # as stored before the options were recorded
    open_stored(old, ["maximize"], url)
    with pytest.warns(StudyOptionsUncheckedWarning, match="could not check"):
        study = run_study(evaluator, url, resume=True)
    assert len(study.get_trials()) == 2


def test_an_existing_study_is_an_output_refusal(flfm, tmp_path):
    from lfm_studio.engine.io.file_checks import OutputError
    from lfm_studio.engine.optimize.study import StudyExistsError

    url = f"sqlite:///{tmp_path / 'e.db'}"
    run_study(Evaluator(flfm, ONE_POINT, [Photons()]), url, n_trials=1)
    with pytest.raises(StudyExistsError, match="already exists") as caught:
        run_study(Evaluator(flfm, ONE_POINT, [Photons()]), url)
    assert isinstance(caught.value, OutputError)


def test_a_resume_with_other_objectives_names_them_in_plain_words(flfm, tmp_path):
    url = f"sqlite:///{tmp_path / 'o.db'}"
    run_study(Evaluator(flfm, ONE_POINT, [Photons()]), url, n_trials=1)
    with pytest.raises(StudyMismatchError, match=r"was made with other objectives; resuming it with these"):
        run_study(Evaluator(flfm, ONE_POINT, [Counting()]), url, resume=True)
