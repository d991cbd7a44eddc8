"""``lfm-studio optimize`` and ``lfm-studio study show`` on a toy space with a known optimum."""

from __future__ import annotations

import json
import re

import pytest

from lfm_studio.cli import main
from lfm_studio.engine.design import load_design

pytest.importorskip("optuna")


@pytest.fixture
def space(tmp_path):
    """Lenslet apertures 400-700 um on the FLFM's 600 um pitch: 700 overlaps, 600 has the largest NA."""
    path = tmp_path / "space.json"
    path.write_text(
        json.dumps(
            {
                "parameters": [
                    {"path": "mla.lenslets[*].aperture_diameter_um", "low": 400, "high": 700, "step": 100}
                ]
            }
        )
    )
    return path


def _run(tmp_path, space, *extra):
    return main(
        [
            "optimize", "flfm_guo2019", "--space", str(space), "--objective", "effective_numerical_aperture",
            "--study", f"sqlite:///{tmp_path / 'study.db'}", "--out", str(tmp_path / "best.json"), *extra,
        ]
    )  # fmt: skip


def test_optimize_writes_the_best_design_and_refuses_to_overwrite(tmp_path, space, capsys):
    assert _run(tmp_path, space) == 0
    out = capsys.readouterr().out
    assert "complete 3, infeasible 1" in out and "lenslet_overlap" in out
    assert "best design (trial 2): mla.lenslets[*].aperture_diameter_um=600.0" in out
    best = load_design(tmp_path / "best.json")
    assert {lens.aperture_diameter_um for lens in best.mla.lenslets} == {600.0}
    assert "optimised, trial 2" in best.name
    before = (tmp_path / "best.json").read_bytes()
    assert _run(tmp_path, space, "--resume") == 3  # --out exists: refused before any work
    assert "pass --overwrite" in capsys.readouterr().err
    assert (tmp_path / "best.json").read_bytes() == before
    assert _run(tmp_path, space) == 3  # still refused: the output check comes first
    capsys.readouterr()
    assert _run(tmp_path, space, "--overwrite") == 3  # the study exists (output refused): --resume needed
    assert "--resume" in capsys.readouterr().err
    assert _run(tmp_path, space, "--resume", "--overwrite") == 0  # nothing left to evaluate
    assert load_design(tmp_path / "best.json").mla.lenslets[0].aperture_diameter_um == 600.0


def test_study_show_prints_the_table_and_the_pareto_front(tmp_path, space, capsys):
    code = main(
        [
            "optimize", "flfm_guo2019", "--space", str(space),
            "--objective", "effective_numerical_aperture,depth_of_field",
            "--study", str(tmp_path / "two.db"), "--out", str(tmp_path / "best.json"),
        ]
    )  # fmt: skip
    assert code == 0
    capsys.readouterr()
    assert main(["study", "show", str(tmp_path / "two.db")]) == 0
    out = capsys.readouterr().out
    assert "effective_numerical_aperture [-] (max)" in out and "depth_of_field [um] (max)" in out
    assert "Pareto front (3 candidates)" in out
    assert out.count("complete") >= 3 and "lenslet_overlap" in out


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--objective", "sharpness"], "objective must be one of"),
        (["--objective", "effective_numerical_aperture", "--sampler", "cmaes"], None),
    ],
)
def test_bad_input_is_refused_with_a_reason(tmp_path, space, capsys, args, message):
    code = main(
        ["optimize", "flfm_guo2019", "--space", str(space), "--study", str(tmp_path / "s.db"),
         "--out", str(tmp_path / "best.json"), "--trials", "2", *args]
    )  # fmt: skip
    err = capsys.readouterr().err
    if message is None:  # cmaes: runs where the cmaes package is installed, else a named refusal
        assert code == 0 or (code == 2 and "pip install cmaes" in err)
    else:
        assert code == 2 and message in err
    assert code == 0 or not (tmp_path / "best.json").exists()


def test_missing_space_and_study_files(tmp_path, capsys):
    code = main(["optimize", "flfm_guo2019", "--space", str(tmp_path / "none.json"), "--objective",
                 "depth_of_field", "--out", str(tmp_path / "b.json"), "--study", str(tmp_path / "s.db")])  # fmt: skip
    assert code == 2 and "no such file" in capsys.readouterr().err
    assert main(["study", "show", str(tmp_path / "none.db")]) == 2
    assert "no such study database" in capsys.readouterr().err


def test_task_objective_through_the_cli(tmp_path, capsys):
    """A task score (RL of held-out beads) from the command line, on a 128 px crop and 3 depths."""
    space = tmp_path / "space.json"
    space.write_text(
        json.dumps({"parameters": [{"path": "relay.field_stop_diameter_mm", "choices": [2.66, 3.0]}]})
    )
    code = main(
        [
            "optimize", "flfm_guo2019", "--space", str(space), "--objective", "task_ncc,task_f1",
            "--study", str(tmp_path / "task.db"), "--out", str(tmp_path / "best.json"), "--crop", "128",
            "--depths", "-10:10:10", "--iterations", "5", "--task-seeds", "1000", "--photons", "1e4",
        ]
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0
    assert "complete 1, infeasible 1" in out and "sub_image_overlap" in out  # 3.0 mm: sub-images overlap
    assert "task_ncc" in out and "best design (trial 0)" in out
    assert load_design(tmp_path / "best.json").relay.field_stop_diameter_mm == 2.66
    # walk4 #2: a resume with other task options is refused before any work, naming each
    code = main(
        [
            "optimize", "flfm_guo2019", "--space", str(space), "--objective", "task_ncc,task_f1",
            "--study", str(tmp_path / "task.db"), "--out", str(tmp_path / "best.json"), "--crop", "128",
            "--depths", "-10:10:10", "--iterations", "2", "--task-seeds", "5,6", "--photons", "1e4",
            "--resume", "--overwrite",
        ]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert (
        code == 2
        and "task_ncc iterations: stored 5, now 2" in err
        and "task_ncc seeds: stored [1000], now [5, 6]" in err
    )


def _algorithm2(tmp_path, *extra):
    return main(
        [
            "optimize", "flfm_guo2019", "--algorithm2", "--min-lenslet-um", "600", "--sizes", "2",
            "--objective", "effective_numerical_aperture", "--study", f"sqlite:///{tmp_path / 'a2.db'}",
            "--out", str(tmp_path / "a2.json"), *extra,
        ]
    )  # fmt: skip


@pytest.mark.filterwarnings(
    "ignore::lfm_studio.engine.design.errors.DesignWarning"
)  # 1.2 mm lenslets undersample
def test_algorithm2_through_the_cli_stores_every_layout_and_resumes(tmp_path, capsys):
    """FLFM pupil on 600 um cells, 2x2 merges: merging doubles a lenslet's aperture, so its NA."""
    from lfm_studio.engine.optimize.study import load_study, record_of

    assert _algorithm2(tmp_path) == 0
    out = capsys.readouterr().out
    assert "0 from the study" in out and "wrote" in out
    study = load_study(str(tmp_path / "a2.db"))
    complete = [t for t in study.trials if t.state.name == "COMPLETE"]
    failed = len(study.trials) - len(complete)  # the counts add up to the layouts stored (walk4 #7)
    assert f"{len(study.trials)} layouts: {len(complete)} scored now, {failed} infeasible" in out
    initial = next(t for t in complete if t.params["base"] == "initial")
    best = load_design(tmp_path / "a2.json")
    apertures = {lens.aperture_diameter_um for lens in best.mla.lenslets}
    assert apertures == {600.0, 1200.0}  # one cell and one 2x2 block
    assert max(t.values[0] for t in complete) == pytest.approx(2 * initial.values[0], rel=1e-9)
    assert all(record_of(t)["infeasible_reason"] for t in study.trials if t.state.name == "FAIL")
    stored = len(study.trials)
    assert _algorithm2(tmp_path, "--resume", "--overwrite") == 0
    out = capsys.readouterr().out
    found = re.search(r"(\d+) layouts: 0 scored now, (\d+) infeasible, (\d+) from the study", out)
    # refused layouts are refused again by the layout checks (nothing built); the rest come from the study
    assert (
        found and int(found[1]) == stored == int(found[2]) + int(found[3]) and int(found[3]) >= len(complete)
    )
    assert load_design(tmp_path / "a2.json").mla.count == best.mla.count


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--space", "space.json"], "does not apply to --algorithm2"),
        (["--objective", "lateral_resolution,axial_resolution"], "optimises one objective"),
        (["--symmetry", "5-fold"], "symmetry must be one of"),
    ],
)
def test_algorithm2_bad_input(tmp_path, capsys, args, message):
    code = _algorithm2(tmp_path, *args)
    assert code == 2 and message in capsys.readouterr().err
    assert not (tmp_path / "a2.json").exists()


def test_algorithm2_needs_the_cell_size(tmp_path, capsys):
    code = main(["optimize", "flfm_guo2019", "--algorithm2", "--objective", "axial_crb",
                 "--study", str(tmp_path / "s.db"), "--out", str(tmp_path / "b.json")])  # fmt: skip
    assert code == 2 and "needs --min-lenslet-um" in capsys.readouterr().err


@pytest.mark.filterwarnings("ignore::lfm_studio.engine.design.errors.DesignWarning")
def test_a_crop_without_views_warns_and_the_default_crop_adapts(tmp_path, capsys):
    """xlfm_cong2017: --crop 256 holds none of the 27 sub-image centres, task_ncc stays at the all-zero
    floor, and both warnings name --crop 512; without --crop the run takes 512 px by itself."""
    space = tmp_path / "space.json"
    space.write_text(json.dumps({"parameters": [{"path": "relay.focal_length_mm", "choices": [160]}]}))

    def run(name, *extra):
        return main(
            [
                "optimize", "xlfm_cong2017", "--space", str(space), "--objective", "task_ncc",
                "--study", str(tmp_path / f"{name}.db"), "--out", str(tmp_path / f"{name}.json"),
                "--depths", "-20:20:20", "--iterations", "10", "--task-seeds", "1000", *extra,
            ]
        )  # fmt: skip

    assert run("tails", "--crop", "256") == 0
    captured = capsys.readouterr()
    assert "--crop 256: the 256 px crop holds 0 of the 27 sub-image centres" in captured.err
    assert "the best candidate's task_ncc 0.0" in captured.err
    assert "does not beat the all-zero volume's score by the margin" in captured.err
    assert captured.err.count("Fix: --crop 512") == 1 and "rerun with --crop 512" in captured.err
    assert run("auto") == 0
    captured = capsys.readouterr()
    assert "PSF crop: 512 px (automatic; the 512 px crop holds 3 of the 27 sub-image centres" in captured.out
    assert "warning" not in captured.err
    from lfm_studio.engine.optimize.study import load_study, record_of

    study = load_study(str(tmp_path / "auto.db"))
    assert study.user_attrs["settings"]["crop"] == 512
    assert record_of(study.trials[0])["at_floor"] == [] and study.trials[0].values[0] > 0.3
    # Resuming without --crop keeps the stored study's crop (no automatic crop, no mismatch).
    assert run("tails", "--resume", "--overwrite") == 0
    captured = capsys.readouterr()
    assert "PSF crop" not in captured.out and "--crop 256: the 256 px crop holds 0" in captured.err


def test_ctrl_c_says_what_the_study_kept_and_how_to_continue(tmp_path, space, capsys, monkeypatch):
    from lfm_studio.engine.optimize import Evaluator

    score = Evaluator.__call__
    calls = []

    def interrupted_at_the_third(self, params):
        calls.append(params)
        if len(calls) == 3:
            raise KeyboardInterrupt  # Ctrl+C while the third candidate is evaluated
        return score(self, params)

    monkeypatch.setattr(Evaluator, "__call__", interrupted_at_the_third)
    assert _run(tmp_path, space) == 130
    err = capsys.readouterr().err
    assert "no output was written" not in err
    assert "keeps its 2 finished trial(s)" in err and f"--out {tmp_path / 'best.json'} was not written" in err
    assert "Fix: run the same command with --resume" in err
    assert main(["study", "show", str(tmp_path / "study.db")]) == 0
    shown = capsys.readouterr().out
    assert "running" not in shown.lower() and "interrupted" in shown  # the killed trial is closed
    monkeypatch.setattr(Evaluator, "__call__", score)
    assert _run(tmp_path, space, "--resume") == 0
    assert "complete 3, interrupted 1, infeasible 1" in capsys.readouterr().out


def _crb(tmp_path, name, *extra):
    """axial_crb of one FLFM point (lenslet aperture 600 um) on a 128 px crop and 3 depths."""
    space = tmp_path / "one.json"
    space.write_text(
        json.dumps({"parameters": [{"path": "mla.lenslets[*].aperture_diameter_um", "choices": [600]}]})
    )
    return main(
        [
            "optimize", "flfm_guo2019", "--space", str(space), "--objective", "axial_crb", "--crop", "128",
            "--depths", "-10:10:10", "--study", f"sqlite:///{tmp_path / name}.db",
            "--out", str(tmp_path / f"{name}.json"), *extra,
        ]
    )  # fmt: skip


def _stored(tmp_path, name):
    from lfm_studio.engine.optimize.study import load_study

    study = load_study(str(tmp_path / f"{name}.db"))
    return study.user_attrs["objective_options"]["axial_crb"], study.trials[0].values[0]


def test_axial_crb_defaults_to_the_engine_photons_and_applies_background(tmp_path, capsys):
    """walk4 #3: the CLI scored axial_crb at 1e5 photons (the dock at 1000) and ignored --background."""
    from lfm_studio.engine.optimize.objectives import CRB_BACKGROUND, CRB_PHOTONS

    assert _crb(tmp_path, "plain") == 0
    assert _crb(tmp_path, "dim", "--background", "50") == 0
    plain, dim = _stored(tmp_path, "plain"), _stored(tmp_path, "dim")
    assert plain[0] == {"photons": CRB_PHOTONS, "background": CRB_BACKGROUND}
    assert dim[0] == {"photons": CRB_PHOTONS, "background": 50.0}
    assert dim[1] > plain[1]  # more background, a worse bound


def test_a_resume_with_other_photons_is_refused(tmp_path, capsys):
    """walk4 #2: the resumed trials were scored at other photons and ranked with the stored ones."""
    assert _crb(tmp_path, "s", "--photons", "1e5") == 0
    capsys.readouterr()
    assert _crb(tmp_path, "s", "--resume", "--overwrite", "--photons", "1000") == 2
    err = capsys.readouterr().err
    assert (
        "axial_crb photons: stored 100000.0, now 1000.0" in err
        and "Fix: resume with the stored options" in err
    )
    assert _crb(tmp_path, "s", "--resume", "--overwrite", "--photons", "1e5") == 0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--background", "50"], "--background 50 does not apply to effective_numerical_aperture"),
        (["--photons", "1000"], "--photons 1000 does not apply to effective_numerical_aperture"),
    ],
)
def test_an_option_no_objective_takes_is_refused(tmp_path, space, capsys, args, message):
    assert _run(tmp_path, space, *args) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "best.json").exists()
