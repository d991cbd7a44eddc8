"""Bad inputs found by a new-user walk-through: each refusal names the option as typed, the value and a
fix, exits with the usage status (2) and prints no traceback."""

from __future__ import annotations

import json

import pytest

from lfm_studio.cli import main
from lfm_studio.cli.errors import BAD_INPUT, OUTPUT_REFUSED


def _refused(capsys, argv: list[str], *parts: str) -> str:
    """Run ``argv``; assert exit 2, "error:", no traceback, nothing on stdout and every part in stderr."""
    capsys.readouterr()
    assert main(argv) == BAD_INPUT
    out, err = capsys.readouterr()
    assert out == "" and "error:" in err and "Traceback" not in err and "Errno" not in err, err
    for part in parts:
        assert part in err, (part, err)
    return err


@pytest.fixture
def existing(tmp_path):
    """A file that exists (its content is never read: the refusals come first)."""
    path = tmp_path / "exists.tif"
    path.write_bytes(b"")
    return str(path)


def test_missing_psf_and_image_of_reconstruct_name_the_option(tmp_path, existing, capsys):
    out = str(tmp_path / "rec.tif")
    nope = str(tmp_path / "nope.tif")
    _refused(capsys, ["reconstruct", "--psf", nope, "--image", existing, "--out", out],
             f"--psf {nope}: no such file", "Fix: give the path to a PSF stack TIFF")  # fmt: skip
    _refused(capsys, ["reconstruct", "--psf", existing, "--image", nope, "--out", out],
             f"--image {nope}: no such file", "Fix: give the path to a light-field image TIFF")  # fmt: skip
    _refused(capsys, ["reconstruct", "--psf", existing, "--image", existing, "--calibration", nope, "--out", out],
             f"--calibration {nope}: no such file", "Fix:")  # fmt: skip


def test_missing_truth_and_estimate_of_metrics_name_the_option(tmp_path, existing, capsys):
    nope = str(tmp_path / "nope.tif")
    _refused(capsys, ["metrics", "--truth", nope, "--estimate", existing],
             f"--truth {nope}: no such file", "Fix: give the path to the ground-truth volume TIFF")  # fmt: skip
    _refused(capsys, ["metrics", "--truth", existing, "--estimate", nope],
             f"--estimate {nope}: no such file", "Fix: give the path to the reconstructed volume TIFF")  # fmt: skip
    _refused(capsys, ["metrics", "--truth", str(tmp_path), "--estimate", existing],
             f"--truth {tmp_path}: a folder, not a file", "Fix:")  # fmt: skip


@pytest.mark.parametrize("command", [["info"], ["simulate", "--out", "psf.tif"]])
def test_a_missing_design_file_names_it_and_the_presets(tmp_path, command, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    err = _refused(capsys, [command[0], "missing.json", *command[1:]],
                   "design missing.json: no such design file", "Fix: give the path to a .json design file",
                   "xlfm_cong2017")  # fmt: skip
    assert err.startswith(f"lfm-studio {command[0]}: error: ")
    assert not (tmp_path / "psf.tif").exists()


def test_a_design_folder_and_a_missing_calibrate_design_are_named(tmp_path, existing, capsys):
    _refused(capsys, ["info", str(tmp_path)], f"design {tmp_path}: a folder, not a design file", "Fix:")
    _refused(capsys, ["calibrate", "--radiometry", existing, "--design", "missing.json",
                      "--out", str(tmp_path / "c.json")],
             "--design missing.json: no such design file", "Fix:")  # fmt: skip


def test_gui_with_a_missing_design_file_is_refused_before_qt_starts(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("QT_QPA_PLATFORM", "offscreen")
    _refused(capsys, ["gui", "missing.json"], "design missing.json: no such design file", "Fix:")


def test_image_refuses_a_misspelled_phantom_a_missing_psf_and_a_bad_count(tmp_path, existing, capsys):
    out = str(tmp_path / "lf.tif")
    base = ["image", "flfm_guo2019", "--out", out]
    _refused(capsys, [*base, "--psf", existing, "--phantom", "bead"],
             "--phantom bead: neither a phantom name nor an existing file", "did you mean beads?",
             "Fix: --phantom beads or cells, or the path to a volume TIFF")  # fmt: skip
    nope = str(tmp_path / "nope.tif")
    _refused(capsys, [*base, "--psf", nope], f"--psf {nope}: no such file", "Fix:")
    for count in ("-3", "0"):
        _refused(capsys, [*base, "--psf", existing, "--count", count],
                 f"--count {count}: a phantom needs at least 1 bead", "Fix: --count 1 or more")  # fmt: skip
    assert not (tmp_path / "lf.tif").exists()


@pytest.mark.parametrize(
    ("depths", "fix"),
    [
        ("-50:50:-5", "--depths=-50:50:5"),
        ("50:-50:5", "--depths=-50:50:5"),
        ("nan:5:1", "--depths=-40:40:10"),
    ],
)
def test_simulate_depths_out_of_order_names_the_option_and_a_fix(tmp_path, depths, fix, capsys):
    out = tmp_path / "psf.tif"
    _refused(capsys, ["simulate", "flfm_guo2019", f"--depths={depths}", "--out", str(out)],
             "--depths must be START:STOP:STEP", f"got {depths}", f"Fix: e.g. {fix}.")  # fmt: skip
    assert not out.exists()


def test_a_design_value_error_shows_its_own_fix_once(tmp_path, capsys):
    from lfm_studio.engine.design import design_to_json, load_preset

    data = json.loads(design_to_json(load_preset("flfm_guo2019")))
    data["depths"]["depth_step_um"] = -10
    path = tmp_path / "negative_step.json"
    path.write_text(json.dumps(data))
    err = _refused(
        capsys, ["info", str(path)], "depth_step_um must be a finite number > 0 um; got -10 um. Fix: e.g. 2."
    )
    assert err.count("Fix:") == 1, err


def test_a_design_refused_by_validation_prints_our_message_without_pydantic_wrapping(capsys):
    """--voxels-per-lenslet 0 makes the design's accuracy invalid inside pydantic: the refusal is our
    sentence (parameter, value, fix), not "1 validation error for ... [type=value_error, ...]"."""
    err = _refused(
        capsys,
        ["resolution", "flfm_guo2019", "--voxels-per-lenslet", "0"],
        "voxels_per_lenslet must be an odd integer >= 1 (a voxel on each lenslet centre); got 0. Fix: e.g. 5",
    )
    for boilerplate in (
        "validation error for",
        "[type=",
        "input_value",
        "errors.pydantic.dev",
        "Value error, ",
    ):
        assert boilerplate not in err, err


def test_gui_help_lists_the_presets(capsys):
    """The preset names appeared only in the error for an unknown one."""
    from lfm_studio.engine.design import list_presets

    with pytest.raises(SystemExit) as exit_:
        main(["gui", "--help"])
    assert exit_.value.code == 0
    help_text = " ".join(capsys.readouterr().out.split())  # argparse wraps the lines
    assert list_presets() and all(name in help_text for name in list_presets())


def test_a_tiff_output_under_another_name_is_refused_before_the_inputs_are_read(tmp_path, existing, capsys):
    out = str(tmp_path / "rec.png")
    capsys.readouterr()
    assert main(["reconstruct", "--psf", existing, "--image", existing, "--out", out]) == OUTPUT_REFUSED
    err = capsys.readouterr().err
    assert f"--out {out} would hold a TIFF, but its name does not end in .tif or .tiff" in err
    assert "Fix: name it rec.tif." in err and not (tmp_path / "rec.png").exists()
