"""Algorithm 2 recorded into a stored Optuna study: every step stored, resumable without re-scoring."""

from __future__ import annotations

import json
import threading
import warnings
from dataclasses import dataclass, field

import pytest

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.design.design_io import design_from_json
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.optimize.algorithm2 import algorithm2
from lfm_studio.engine.optimize.algorithm2_study import layout_blocks, layout_key, run_algorithm2_study
from lfm_studio.engine.optimize.mla_cells import Block, MLAPlane
from lfm_studio.engine.optimize.study import StudyMismatchError, record_of
from lfm_studio.engine.progress import CancelledError

pytest.importorskip("optuna")

SIZES = [2, 3, 4]


@pytest.fixture(scope="module")
def xlfm():
    return load_preset("xlfm_cong2017")


def lopsided(design) -> float:
    """An asymmetric toy score (as in test_algorithm2): large lenslets right (+x) and top (+y)."""
    return sum(
        lens.aperture_diameter_um**2 * (1.0 + 1e-4 * lens.center_um[0] + 3e-5 * lens.center_um[1])
        for lens in design.mla.lenslets
        if lens.aperture_diameter_um > 2000.0
    )


@dataclass
class Lopsided:
    """The toy score as an objective of a candidate, counting the layouts it scores."""

    name: str = "lopsided"
    unit: str = "um^2"
    direction: str = "maximize"
    seen: list = field(default_factory=list)
    stop: threading.Event | None = None
    stop_after: int = 0

    def __call__(self, candidate) -> float:
        self.seen.append(
            tuple((lens.center_um, lens.aperture_diameter_um) for lens in candidate.design.mla.lenslets)
        )
        if self.stop is not None and len(self.seen) >= self.stop_after:
            self.stop.set()  # "kill" the run after this layout is stored
        return lopsided(candidate.design)


def run(xlfm, db, objective, **kwargs):
    return run_algorithm2_study(
        xlfm, objective, db, min_lenslet_um=2000.0, sizes=SIZES, constraints=(), **kwargs
    )


def steps(study):
    out = []
    for trial in study.get_trials(deepcopy=False):
        record = record_of(trial)
        value = trial.values[0] if trial.state.name == "COMPLETE" else None
        out.append((record["algorithm2"]["index"], record["layout"], value, record["infeasible_reason"]))
    return sorted(out)


def test_every_step_is_stored_like_a_study_trial(xlfm, tmp_path):
    plain = []
    reference = algorithm2(
        xlfm, lopsided, plane=MLAPlane.from_design(xlfm, 2000.0), sizes=SIZES, record=plain.append
    )
    result, study = run(xlfm, f"sqlite:///{tmp_path / 's.db'}", Lopsided())
    assert result.blocks == reference.blocks and result.score == pytest.approx(reference.score, rel=1e-12)
    stored = steps(study)
    assert [s[0] for s in stored] == [c.index for c in plain]  # every step, once
    for (_index, layout, value, reason), candidate in zip(stored, plain, strict=True):
        assert layout_blocks(layout) == candidate.blocks
        if candidate.score is None:
            assert value is None and reason  # infeasible, with its reason
        else:
            assert value == pytest.approx(candidate.score, rel=1e-12) and reason is None
    best = max((t for t in study.trials if t.state.name == "COMPLETE"), key=lambda t: t.values[0])
    record = record_of(best)
    assert layout_blocks(record["layout"]) == reference.blocks
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)  # the toy score tolerates overlapping sub-images
        assert design_from_json(record["design_json"]).mla.count == len(reference.blocks)
    assert record["timing"]["total_s"] >= 0.0 and "seed" in record
    assert study.user_attrs["sampler"] == "algorithm2"
    assert study.user_attrs["space"]["algorithm2"]["sizes"] == SIZES
    assert {"size", "i", "j", "base"} == set(best.params)


def test_on_step_sees_every_stored_step_with_its_record(xlfm, tmp_path):
    seen = []
    _, study = run(
        xlfm, str(tmp_path / "s.db"), Lopsided(), on_step=lambda step, record: seen.append((step, record))
    )
    stored = steps(study)
    assert [step.index for step, _ in seen] == [s[0] for s in stored]
    for (step, record), (_index, layout, value, reason) in zip(seen, stored, strict=True):
        assert record["layout"] == layout == layout_key(step.blocks) and record["infeasible_reason"] == reason
        assert (value is None) == (step.score is None) and (record["design_json"] is None) == (
            step.design is None
        )


def test_layout_key_round_trip():
    blocks = (Block(0, 1, 2), Block(3, 3, 1))
    assert json.loads(layout_key(blocks)) == [[0, 1, 2], [3, 3, 1]]
    assert layout_blocks(layout_key(blocks)) == blocks


def test_killed_run_resumes_without_rescoring(xlfm, tmp_path):
    whole = Lopsided()
    _, uninterrupted = run(xlfm, f"sqlite:///{tmp_path / 'whole.db'}", whole)
    db = f"sqlite:///{tmp_path / 'killed.db'}"
    first = Lopsided(stop=threading.Event(), stop_after=4)
    with pytest.raises(CancelledError):
        run(xlfm, db, first, cancel=first.stop)
    assert len(first.seen) == 4
    again = Lopsided()
    result, resumed = run(xlfm, db, again, resume=True)
    assert not set(first.seen) & set(again.seen)  # no stored layout scored again
    assert sorted(first.seen + again.seen) == sorted(whole.seen)
    assert result.reused == 4 and result.evaluated == len(whole.seen) - 4
    for a, b in zip(steps(resumed), steps(uninterrupted), strict=True):
        assert a[:2] == b[:2] and a[3] == b[3]
        assert (a[2] is None and b[2] is None) or a[2] == pytest.approx(b[2], rel=1e-12)
    # Resuming a finished study scores nothing and stores nothing new.
    idle = Lopsided()
    _, same = run(xlfm, db, idle, resume=True)
    assert idle.seen == [] and len(same.trials) == len(resumed.trials)


def test_resume_refuses_another_search(xlfm, tmp_path):
    db = f"sqlite:///{tmp_path / 's.db'}"
    run(xlfm, db, Lopsided())
    with pytest.raises(ValueError, match="already exists"):
        run(xlfm, db, Lopsided())
    with pytest.raises(StudyMismatchError, match="space"):
        run_algorithm2_study(
            xlfm,
            Lopsided(),
            db,
            min_lenslet_um=2000.0,
            sizes=SIZES,
            symmetry="mirror",
            constraints=(),
            resume=True,
        )
