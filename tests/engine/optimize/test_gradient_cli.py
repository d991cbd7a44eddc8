"""``lfm-studio optimize --gradient psf|end-to-end`` and ``study show`` on the tiny five-lenslet FLFM."""

from __future__ import annotations

import warnings

import pytest

from lfm_studio.cli import main
from lfm_studio.engine.design import load_design, save_design
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.optimize import DesignSpace, Parameter

from .conftest import tiny_flfm

optuna = pytest.importorskip("optuna")

SPACE = DesignSpace(
    (
        Parameter("mla.lenslets[*].focal_length_mm", 12.0, 24.0),
        Parameter("mla_to_camera_distance_mm", 14.0, 20.0),
    )
)


@pytest.fixture
def files(tmp_path):
    """A 280 px sensor (the sub-images fit: the default constraints pass), out of focus."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        design = SPACE.apply(
            tiny_flfm(pixels=280),
            {"mla.lenslets[*].focal_length_mm": 22.0, "mla_to_camera_distance_mm": 15.0},
        )
        save_design(design, tmp_path / "tiny.json")
    (tmp_path / "space.json").write_text(SPACE.to_json())
    return tmp_path


def _optimize(path, *extra):
    return main(
        [
            "optimize", str(path / "tiny.json"), "--space", str(path / "space.json"), "--crop", "280",
            "--study", f"sqlite:///{path / 'g.db'}", "--out", str(path / "best.json"), *extra,
        ]
    )  # fmt: skip


def test_gradient_psf_writes_the_design_and_the_study_lists_every_step(files, capsys):
    code = _optimize(
        files, "--gradient", "psf", "--objective", "axial_crb", "--steps", "3", "--lr", "0.05",
        "--photons", "1000", "--catalogue", "10,16.8,20,26",
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0, out
    assert "step   2  axial_crb" in out and "snapped to the catalogue" in out
    assert "float32 vs float64 start gradient: relative difference" in out and "within" in out
    best = load_design(files / "best.json")
    assert "gradient psf" in best.name
    summary = optuna.load_study(study_name="lfm_study", storage=f"sqlite:///{files / 'g.db'}").user_attrs[
        "gradient"
    ]
    assert summary["final_value_at"] == "final_point"
    start, written = summary["start_value"], summary["snapped_value"]  # the design written is snapped
    assert f"axial_crb {start:.6g} -> {written:.6g} um (snapped to the catalogue)" in best.description
    assert {lens.focal_length_mm for lens in best.mla.lenslets} <= {10.0, 16.8, 20.0, 26.0}
    assert main(["study", "show", str(files / "g.db")]) == 0
    shown = capsys.readouterr().out
    assert "complete 4" in shown and "axial_crb [um] (min)" in shown  # 3 steps and the last point
    (files / "best.json").unlink()
    assert _optimize(files, "--gradient", "psf", "--steps", "1") == 3  # the study exists (output refused)
    assert "already exists" in capsys.readouterr().err
    code = _optimize(
        files, "--gradient", "psf", "--objective", "axial_crb", "--steps", "5", "--lr", "0.05",
        "--photons", "1000", "--catalogue", "10,16.8,20,26", "--resume",
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0, out
    assert "resumed: 3 stored steps" in out and "step   4  axial_crb" in out
    assert "the design written is the best point" in out
    # walk4 #2: resuming with other photons would mix two settings' CRBs in one study
    code = _optimize(
        files, "--gradient", "psf", "--steps", "6", "--photons", "1e5", "--resume", "--overwrite",
        "--catalogue", "10,16.8,20,26",
    )  # fmt: skip
    assert code == 2 and "axial_crb photons: stored 1000.0, now 100000.0" in capsys.readouterr().err


def test_gradient_end_to_end_refuses_an_objective_and_both_sides_frozen(files, capsys):
    assert _optimize(files, "--gradient", "end-to-end", "--objective", "axial_crb") == 2
    assert "--objective does not apply" in capsys.readouterr().err
    code = _optimize(
        files, "--gradient", "end-to-end", "--reconstruction", "rl", "--freeze-optics", "--steps", "1"
    )
    assert code == 2 and "nothing to optimise" in capsys.readouterr().err


@pytest.mark.parametrize("catalogue", [(), ("--catalogue", "10,16.8,20,26")], ids=["continuous", "snapped"])
def test_gradient_end_to_end_reports_the_training_loss_where_it_was_measured(files, capsys, catalogue):
    """The last step's training loss is measured before its update: the CLI, the design file and
    the study never present it as the final design's value (that is the held-out loss)."""
    code = _optimize(
        files, "--gradient", "end-to-end", "--steps", "2", "--batch", "1", "--held-out", "1",
        "--unrolled-iterations", "2", "--photons", "20000", "--no-float64-check", *catalogue,
    )  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0, out
    study = optuna.load_study(study_name="lfm_study", storage=f"sqlite:///{files / 'g.db'}")
    summary = study.user_attrs["gradient"]
    start, last = summary["start_value"], summary["final_value"]  # kept for older readers
    held_start, held_final = summary["held_out_start"], summary["held_out_final"]
    assert summary["final_value_at"] == "before_last_update"
    assert f"task_loss: start {start:.6g}, final {last:.6g}" not in out
    assert (
        f"task_loss (training batches): {start:.6g} at step 0, {last:.6g} at step 1, each measured before "
        "its step's update (not evaluated at the final design;"
    ) in out
    where = "the final point (before snapping)" if catalogue else "the final design"
    assert f"held-out task loss: start {held_start:.6g}, final {held_final:.6g} at {where}" in out
    written = summary["held_out_snapped"] if catalogue else held_final
    description = load_design(files / "best.json").description
    assert f"held-out task loss {held_start:.6g} -> {written:.6g} at the final design" in description
    assert f"{last:.6g}" not in description


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--gradient", "end-to-end", "--background", "5"], "--background 5 does not apply to --gradient end-to-end"),
        (["--gradient", "psf", "--objective", "mtf_support", "--background", "5"], "--background 5 does not apply to mtf_support"),
    ],
)  # fmt: skip
def test_gradient_refuses_a_background_its_objective_does_not_take(files, capsys, extra, message):
    """walk4 #3: --background was silently ignored where no objective takes it."""
    assert _optimize(files, "--steps", "1", *extra) == 2
    assert message in capsys.readouterr().err
    assert not (files / "best.json").exists()
