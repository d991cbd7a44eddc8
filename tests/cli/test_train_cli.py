"""``lfm-studio train`` the way a user runs it: a design file in, a checkpoint out, refusals by exit code."""

from __future__ import annotations

import re
import warnings

import pytest
import torch

from lfm_studio.cli import main
from lfm_studio.engine.design import save_design
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.learned.checkpoint import read_checkpoint
from tests.engine.reconstruct.conftest import _shrink


@pytest.fixture()
def design_file(tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        design = _shrink("flfm_guo2019", 256, (-10.0, 10.0), 10.0)
    path = tmp_path / "tiny.json"
    save_design(design, path)
    return path


def test_train_writes_a_checkpoint_tied_to_the_design_and_resumes(design_file, tmp_path, capsys):
    out = tmp_path / "model.safetensors"
    threads = torch.get_num_threads()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        code = main(["--threads", "1", "train", str(design_file), "--steps", "3", "--out", str(out)])
        assert code == 0
        printed = capsys.readouterr().out
        assert "unrolled-rl" in printed and "3 steps" in printed and "all-zero volume: 2.0" in printed
        header, _ = read_checkpoint(out)
        assert header.design_hash is not None and len(header.depths) == 3 and header.training["steps"] == 3
        assert main(["train", str(design_file), "--steps", "1", "--out", str(out)]) == 3  # exists: refused
        assert "exists. Fix: choose another --out or pass --overwrite" in capsys.readouterr().err
        assert main(["train", str(design_file), "--steps", "2", "--out", str(out), "--resume"]) == 0
    assert read_checkpoint(out)[0].training["steps"] == 5
    # this run's steps beside this run's seconds, the checkpoint's total after them
    assert re.search(r", 2 steps in \d+ s \(5 in all\) \(stopped: steps\)", capsys.readouterr().out)
    torch.set_num_threads(threads)


def test_reconstruct_applies_a_trained_checkpoint_and_refuses_one_for_another_design(
    design_file, tmp_path, capsys
):
    from lfm_studio.engine.image_quality import ncc
    from lfm_studio.engine.io import read_volume

    paths = {name: tmp_path / f"{name}.tif" for name in ("psf", "lf", "truth", "vol")}
    model = tmp_path / "model.safetensors"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        assert main(["simulate", str(design_file), "--out", str(paths["psf"])]) == 0
        assert main(["image", str(design_file), "--psf", str(paths["psf"]), "--count", "3", "--photons", "1e6",
                     "--out", str(paths["lf"]), "--truth", str(paths["truth"])]) == 0  # fmt: skip
        assert main(["--threads", "1", "train", str(design_file), "--psf", str(paths["psf"]), "--steps", "2",
                     "--out", str(model)]) == 0  # fmt: skip
        base = ["reconstruct", "--psf", str(paths["psf"]), "--image", str(paths["lf"]), "--method", "learned"]
        assert main([*base, "--out", str(paths["vol"])]) == 2
        assert "needs a checkpoint: --model" in capsys.readouterr().err
        assert main([*base, "--model", str(model), "--out", str(paths["vol"])]) == 0
        volume, truth = read_volume(paths["vol"]).data, read_volume(paths["truth"]).data
        assert float(ncc(truth, volume)) > 0.3 and float(volume.std()) > 0
        other = tmp_path / "other.json"
        save_design(_shrink("flfm_guo2019", 256, (-10.0, 10.0), 10.0).updated(wavelength_nm=600.0), other)
        foreign = tmp_path / "foreign.safetensors"
        assert main(["train", str(other), "--steps", "1", "--out", str(foreign)]) == 0
        capsys.readouterr()
        assert main([*base, "--model", str(foreign), "--out", str(tmp_path / "v2.tif")]) == 2
    assert "trained for another design" in capsys.readouterr().err


def test_optics_jitter_is_validated_and_recorded(design_file, tmp_path, capsys):
    out = tmp_path / "model.safetensors"
    with pytest.raises(SystemExit) as caught:
        main(["train", str(design_file), "--steps", "1", "--optics-jitter", "0.5", "--out", str(out)])
    assert caught.value.code == 2
    err = capsys.readouterr().err
    assert "--optics-jitter must be a relative jitter between 0 and 0.2; got '0.5'" in err
    assert "Fix: give a fraction, e.g. --optics-jitter 0.03" in err and not out.exists()
    threads = torch.get_num_threads()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        code = main(["--threads", "1", "train", str(design_file), "--steps", "1", "--optics-jitter", "0.03",
                     "--out", str(out)])  # fmt: skip
    torch.set_num_threads(threads)
    assert code == 0 and read_checkpoint(out)[0].data["optics_jitter"] == 0.03


def test_config_sets_the_model_options_and_refuses_unknown_ones(design_file, tmp_path, capsys):
    out = tmp_path / "model.safetensors"
    threads = torch.get_num_threads()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        args = ["--threads", "1", "train", str(design_file), "--steps", "1", "--out", str(out)]
        assert main([*args, "--config", '{"iterations": 2}']) == 0
        header, _ = read_checkpoint(out)
        assert header.model == "unrolled-rl" and header.config["iterations"] == 2
        with pytest.raises(SystemExit):  # argparse: not a JSON object
            main([*args, "--overwrite", "--config", "[2]"])
        assert "--config must be a JSON object" in capsys.readouterr().err
        code = main([*args, "--overwrite", "--config", '{"iteratoins": 2}'])
        assert code != 0
        err = capsys.readouterr().err
        assert "has no option 'iteratoins'" in err and "iterations" in err
    assert read_checkpoint(out)[0].config["iterations"] == 2  # the refused run left the file as it was
    torch.set_num_threads(threads)
