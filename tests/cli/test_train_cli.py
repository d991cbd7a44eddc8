"""``lfm-studio train`` the way a user runs it: a design file in, a checkpoint out, refusals by exit code."""

from __future__ import annotations

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
    torch.set_num_threads(threads)
