"""``lfm-studio simulate`` and ``image`` on a small Fourier design: files, metadata, errors."""

from __future__ import annotations

import pytest
import torch

from lfm_studio.cli import main
from lfm_studio.engine.design import load_preset, save_design
from lfm_studio.engine.io import read_image, read_psf_stack, read_volume


@pytest.fixture
def small_design(tmp_path):
    design = load_preset("flfm_guo2019")
    camera = design.camera.model_copy(update={"pixel_count": (512, 512)})
    small = design.updated(
        camera=type(design.camera)(**camera.model_dump()),
        depths=type(design.depths)(depth_range_um=(-20.0, 20.0), depth_step_um=20.0),
    )
    path = tmp_path / "small.json"
    save_design(small, path)
    return path


def test_simulate_then_image_writes_consistent_files(tmp_path, small_design, capsys):
    psf_path, lf_path, truth_path = tmp_path / "psf.tif", tmp_path / "lf.tif", tmp_path / "truth.tif"
    assert main(["simulate", str(small_design), "--out", str(psf_path)]) == 0
    stack = read_psf_stack(psf_path)
    assert stack.data.shape == (3, 512, 512)
    assert stack.depths == pytest.approx((-20e-6, 0.0, 20e-6), abs=1e-12)
    assert stack.design is not None and stack.design.camera.pixel_count == (512, 512)
    code = main([
        "image", str(small_design), "--psf", str(psf_path), "--phantom", "beads", "--count", "3",
        "--photons", "1e5", "--seed", "7", "--out", str(lf_path), "--truth", str(truth_path),
    ])  # fmt: skip
    assert code == 0
    image, truth = read_image(lf_path), read_volume(truth_path)
    assert image.data.shape == (512, 512) and image.pixel_size == pytest.approx(6.5e-6, rel=1e-9)
    assert int((truth.data > 0).sum()) == 3
    # Counts: baseline + gain * QE * photons (+ noise): the image total matches the budget.
    design = stack.design
    signal = float((image.data - design.camera.baseline_adu).sum())
    expected = 1e5 * design.camera.quantum_efficiency * design.camera.gain_adu_per_e
    assert signal == pytest.approx(expected, rel=0.05)
    # Same seed, same image.
    again = tmp_path / "again.tif"
    main(
        [
            "image",
            str(small_design),
            "--psf",
            str(psf_path),
            "--count",
            "3",
            "--photons",
            "1e5",
            "--seed",
            "7",
            "--out",
            str(again),
        ]
    )
    assert torch.equal(read_image(again).data, image.data)


def test_existing_output_is_not_overwritten(tmp_path, small_design, capsys):
    out = tmp_path / "psf.tif"
    out.write_bytes(b"user data")
    assert main(["simulate", str(small_design), "--out", str(out)]) == 3  # output refused
    assert "exists. Fix: choose another --out or pass --overwrite" in capsys.readouterr().err
    assert out.read_bytes() == b"user data"


def test_bad_design_gives_a_named_error_without_traceback(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text('{"schema_version": 1, "kind": "fourier"}')
    assert main(["simulate", str(bad), "--out", str(tmp_path / "x.tif")]) == 2
    assert "lfm-studio simulate: error:" in capsys.readouterr().err


def test_conventional_design_round_trips_patterns_through_tiff(tmp_path):
    # A 10x/0.3 conventional design on a small sensor: 6 x 6 lenslets, 3 depths.
    design = load_preset("lfm_10x_na03")
    camera = type(design.camera)(**{**design.camera.model_dump(), "pixel_count": (130, 130)})
    small = design.updated(
        camera=camera, depths=type(design.depths)(depth_range_um=(-20.0, 20.0), depth_step_um=20.0)
    )
    path = tmp_path / "conventional.json"
    save_design(small, path)
    psf_path, lf_path = tmp_path / "patterns.tif", tmp_path / "lf.tif"
    assert main(["simulate", str(path), "--out", str(psf_path), "--dtype", "float64"]) == 0
    stack = read_psf_stack(psf_path)
    assert stack.data.ndim == 5 and stack.patterns is not None and stack.metadata == {}
    assert stack.patterns.lenslets == (6, 6) and len(stack.patterns.reach) == 3
    assert (
        main(
            ["image", str(path), "--psf", str(psf_path), "--count", "2", "--seed", "3", "--out", str(lf_path)]
        )
        == 0
    )
    image = read_image(lf_path)
    q = stack.patterns.pixels_per_lenslet
    assert image.data.shape == (6 * q, 6 * q)
    assert float(image.data.sum()) > 0
