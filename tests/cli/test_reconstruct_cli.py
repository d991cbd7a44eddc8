"""``lfm-studio reconstruct`` and ``metrics``: simulate -> image -> reconstruct -> metrics, frames, errors."""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio import cli
from lfm_studio.cli.reconstruct import add_reconstruct_parsers
from lfm_studio.engine.design import load_preset, save_design
from lfm_studio.engine.io import read_image, read_psf_stack, read_volume, write_image
from lfm_studio.engine.progress import CancelledError
from lfm_studio.engine.reconstruct import registry
from lfm_studio.engine.simulation import imaging_setup

BASELINE = 100.0  # camera baseline (ADU) of the flfm_guo2019 preset; reconstruct reads it from the image


def _has_command(parser: argparse.ArgumentParser, name: str) -> bool:
    return any(
        isinstance(action, argparse._SubParsersAction) and name in action.choices
        for action in parser._actions
    )


def run(argv: list[str]) -> int:
    """``lfm-studio`` main with our sub-commands (the real one once cli.py registers them)."""
    if _has_command(cli.build_parser(), argv[0]):
        return cli.main(argv)
    parser = argparse.ArgumentParser(prog="lfm-studio")
    add_reconstruct_parsers(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    try:  # the error handling of lfm_studio.cli.main
        return int(args.handler(args))
    except (ValueError, FileNotFoundError, FileExistsError) as error:
        print(f"lfm-studio {args.command}: error: {error}", file=sys.stderr)
        return 2


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A small Fourier design (288 px camera: every sub-image on the sensor; 3 depths), its PSF stack,
    a noisy light-field image of 3 beads and the ground truth."""
    folder = tmp_path_factory.mktemp("reconstruct_cli")
    design = load_preset("flfm_guo2019")
    camera = type(design.camera)(**{**design.camera.model_dump(), "pixel_count": (288, 288)})
    small = design.updated(
        camera=camera, depths=type(design.depths)(depth_range_um=(-20.0, 20.0), depth_step_um=20.0)
    )
    paths = {name: folder / f"{name}.tif" for name in ("psf", "lf", "truth")}
    paths["design"] = folder / "small.json"
    save_design(small, paths["design"])
    assert cli.main(["simulate", str(paths["design"]), "--out", str(paths["psf"])]) == 0
    command = ["image", str(paths["design"]), "--psf", str(paths["psf"]), "--count", "3", "--photons", "1e6"]
    assert cli.main([*command, "--seed", "1", "--out", str(paths["lf"]), "--truth", str(paths["truth"])]) == 0
    return paths


@pytest.fixture(scope="module")
def rl_volume(files, tmp_path_factory):
    """An 8-iteration RL reconstruction of the image with the simulated PSF (shared by two tests)."""
    out = tmp_path_factory.mktemp("rl") / "rl8.tif"
    assert _reconstruct(files, out, "--iterations", "8") == 0
    return out


def _reconstruct(files, out, *extra: str) -> int:
    return run(
        ["reconstruct", "--psf", str(files["psf"]), "--image", str(files["lf"]), "--out", str(out), *extra]
    )


def _metrics_json(files, estimate, capsys, *extra: str) -> dict:
    capsys.readouterr()
    assert (
        run(["metrics", "--truth", str(files["truth"]), "--estimate", str(estimate), "--json", *extra]) == 0
    )
    return json.loads(capsys.readouterr().out)


def test_reconstruct_then_metrics_improves_with_iterations(files, rl_volume, tmp_path, capsys):
    few, more = tmp_path / "rl2.tif", rl_volume
    assert _reconstruct(files, few, "--iterations", "2") == 0
    volume, truth = read_volume(more), read_volume(files["truth"])
    setup = imaging_setup(read_psf_stack(files["psf"]))
    assert volume.data.shape == truth.data.shape == setup.volume_shape
    assert volume.voxel_size == pytest.approx(truth.voxel_size, rel=1e-9)
    assert volume.depths == pytest.approx((-20e-6, 0.0, 20e-6), abs=1e-12)
    assert (
        volume.metadata["method"] == "rl-accelerated" and volume.metadata["iterations"] == 8
    )  # the default method
    first = _metrics_json(files, few, capsys, "--normalize", "scale", "--per-depth")
    last = _metrics_json(files, more, capsys, "--normalize", "scale", "--per-depth")
    # More iterations of the default method score higher (measured with plain RL before it became
    # the default: 39.7 -> 41.0 dB, SSIM 0.973 -> 0.990 from 2 to 8 iterations).
    assert last["psnr_db"] > first["psnr_db"] + 0.5 and last["ssim"] > first["ssim"]
    assert len(last["per_depth"]["psnr_db"]) == 3 and last["per_depth"]["depths_um"] == pytest.approx(
        [-20, 0, 20]
    )
    assert last["data_range"] == pytest.approx(float(truth.data.max() - truth.data.min()))
    # The text report says the same.
    assert (
        run(["metrics", "--truth", str(files["truth"]), "--estimate", str(more), "--normalize", "scale"]) == 0
    )
    text = capsys.readouterr().out
    assert f"PSNR {last['psnr_db']:.3f} dB" in text and f"SSIM {last['ssim']:.4f}" in text
    # Explicit data range: PSNR shifts by 20 log10(R'/R).
    scaled = _metrics_json(files, more, capsys, "--normalize", "scale", "--data-range", "10")
    assert scaled["psnr_db"] == pytest.approx(
        last["psnr_db"] + 20 * np.log10(10 / last["data_range"]), abs=1e-9
    )


@pytest.mark.parametrize("method", ["rl-accelerated", "wiener", "tikhonov"])
def test_other_methods_write_a_volume(files, tmp_path, capsys, method):
    out = tmp_path / f"{method}.tif"
    assert _reconstruct(files, out, "--method", method, "--iterations", "3") == 0
    volume = read_volume(out)
    assert volume.metadata["method"] == method and torch.isfinite(volume.data).all()
    report = _metrics_json(files, out, capsys, "--normalize", "scale")
    assert report["ssim"] > 0.9  # measured 0.978 (Wiener) to 0.99


def test_multi_frame_image_gives_a_4d_volume(files, tmp_path, capsys):
    image = read_image(files["lf"])
    # Frame 1 has half the signal above the baseline; the camera metadata comes along.
    half = BASELINE + 0.5 * (image.data - BASELINE)
    paths = {name: tmp_path / f"{name}.tif" for name in ("frames", "half", "series", "single", "single_half")}
    write_image(
        paths["frames"], torch.stack([image.data, half]), pixel_size=image.pixel_size, metadata=image.metadata
    )
    write_image(paths["half"], half, pixel_size=image.pixel_size, metadata=image.metadata)
    for source, out in (("frames", "series"), (files["lf"], "single"), ("half", "single_half")):
        source = paths[source] if isinstance(source, str) else source
        command = ["--image", str(source), "--out", str(paths[out]), "--iterations", "2"]
        assert run(["reconstruct", "--psf", str(files["psf"]), *command]) == 0
    series = read_volume(paths["series"])
    assert series.data.shape == (2, 3, 93, 93) and series.depths is not None
    # Each frame is reconstructed as that frame alone would be (the same code path, frame by frame).
    assert torch.equal(series.data[0], read_volume(paths["single"]).data)
    assert torch.equal(series.data[1], read_volume(paths["single_half"]).data)
    assert 0.4 < float(series.data[1].sum() / series.data[0].sum()) < 0.6  # half the light
    report = _metrics_json(files, paths["series"], capsys)
    assert len(report["frames"]) == 2 and report["frames"][0]["shape"] == [3, 93, 93]


def test_measured_psf_from_a_foreign_tiff(files, rl_volume, tmp_path, capsys):
    stack = read_psf_stack(files["psf"])
    # A bead stack as a camera records it: shifted by (5, -3) px, 200 counts background, Poisson noise.
    shifted = torch.roll(stack.data.double(), shifts=(5, -3), dims=(1, 2))
    counts = torch.poisson(
        shifted * (3e4 / float(shifted.max())) + 200.0, generator=torch.Generator().manual_seed(0)
    )
    beads = tmp_path / "beads.tif"
    tifffile.imwrite(beads, counts.numpy().astype(np.uint16), imagej=True, metadata={"axes": "ZYX"})
    out = tmp_path / "measured.tif"
    base = ["reconstruct", "--psf", str(beads), "--image", str(files["lf"]), "--out", str(out), "--measured"]
    capsys.readouterr()
    assert run([*base, "--iterations", "2"]) == 2
    error = capsys.readouterr().err
    assert "lfm-studio reconstruct: error:" in error and "--depths=START:STOP:STEP" in error
    assert "--magnification" in error and "--wavelength-nm" in error and not out.exists()
    metadata = [
        "--pixel-size-um",
        "6.5",
        "--magnification",
        str(stack.magnification),
        "--wavelength-nm",
        "525",
    ]
    fov = ["--field-of-view-um", str(stack.design.field_of_view_diameter * 1e6)]
    options = ["--iterations", "8", *metadata, *fov, "--depths=-20:20:20"]
    assert run([*base, *options]) == 0
    volume = read_volume(out)
    assert volume.metadata["measured_psf"] is True and volume.data.shape == (3, 93, 93)
    # As good as with the simulated PSF at the same iterations.
    measured = _metrics_json(files, out, capsys, "--normalize", "scale")
    simulated = _metrics_json(files, rl_volume, capsys, "--normalize", "scale")
    print(
        "measured vs simulated PSF:",
        measured["psnr_db"],
        simulated["psnr_db"],
        measured["ssim"],
        simulated["ssim"],
    )
    assert measured["psnr_db"] > simulated["psnr_db"] - 1.0 and measured["ssim"] > simulated["ssim"] - 0.01


def test_existing_output_is_kept_and_errors_are_named(files, tmp_path, capsys):
    out = tmp_path / "vol.tif"
    out.write_bytes(b"user data")
    capsys.readouterr()
    assert _reconstruct(files, out, "--iterations", "1") == 3  # output refused
    assert f"{out} exists. Fix: choose another --out or pass --overwrite" in capsys.readouterr().err
    assert out.read_bytes() == b"user data"
    # A PSF for another sensor size: shape mismatch, exit 2, no traceback, nothing written.
    small = tmp_path / "small_lf.tif"
    write_image(small, torch.ones(100, 100), pixel_size=6.5e-6)
    new = tmp_path / "new.tif"
    capsys.readouterr()
    assert run(["reconstruct", "--psf", str(files["psf"]), "--image", str(small), "--out", str(new)]) == 2
    err = capsys.readouterr().err
    assert "has frames of (100, 100) pixels" in err and "--calibration calib.json" in err and not new.exists()
    assert (
        run(["reconstruct", "--psf", str(tmp_path / "none.tif"), "--image", str(small), "--out", str(new)])
        == 2
    )
    assert f"--psf {tmp_path / 'none.tif'}: no such file. Fix:" in capsys.readouterr().err
    assert _reconstruct(files, new, "--iterations", "0") == 2
    assert "--iterations must be an integer >= 1; got 0" in capsys.readouterr().err
    # metrics: volumes of different shapes, and LPIPS without its package/weights.
    other = tmp_path / "other.tif"
    from lfm_studio.engine.io import write_volume

    write_volume(other, torch.rand(3, 20, 20), voxel_size=(20e-6, 1e-6, 1e-6))
    assert run(["metrics", "--truth", str(files["truth"]), "--estimate", str(other)]) == 2
    assert "has shape (3, 20, 20) but --truth" in capsys.readouterr().err
    truth = str(files["truth"])
    from lfm_studio.engine.image_quality import lpips_available

    if not lpips_available()[0]:
        assert run(["metrics", "--truth", truth, "--estimate", truth, "--lpips"]) == 2
        assert "nothing is downloaded at run time" in capsys.readouterr().err


def test_failed_reconstruction_leaves_no_file(files, tmp_path, monkeypatch, capsys):
    from lfm_studio.engine.reconstruct import builtin_methods as reconstruct  # what the CLI's methods call

    image = read_image(files["lf"])
    frames = tmp_path / "frames.tif"
    write_image(frames, torch.stack([image.data, image.data]), pixel_size=image.pixel_size)
    calls = []
    original = reconstruct.richardson_lucy

    def fail_on_second_frame(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise CancelledError("stopped by the test")
        return original(*args, **kwargs)

    monkeypatch.setattr(reconstruct, "richardson_lucy", fail_on_second_frame)
    out = tmp_path / "out.tif"
    with pytest.raises(CancelledError):
        run(
            [
                "reconstruct",
                "--psf",
                str(files["psf"]),
                "--image",
                str(frames),
                "--out",
                str(out),
                "--iterations",
                "1",
            ]
        )
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["frames.tif"]

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(reconstruct, "richardson_lucy", interrupt)
    assert run(["reconstruct", "--psf", str(files["psf"]), "--image", str(frames), "--out", str(out)]) == 130
    assert "interrupted" in capsys.readouterr().err and not out.exists()


def test_a_registered_method_is_a_choice_with_its_options_and_runs(files, tmp_path, capsys):
    from lfm_studio.engine.image_quality import ncc
    from tests import toy_method

    with toy_method.registered():
        with pytest.raises(SystemExit):
            run(["reconstruct", "--help"])
        text = " ".join(capsys.readouterr().out.split())  # help lines are wrapped
        assert "backprojection: normalised adjoint" in text and "--scale SCALE" in text
        outs = [tmp_path / f"bp{scale}.tif" for scale in (1, 2)]
        for scale, out in zip((1, 2), outs, strict=True):
            assert (
                _reconstruct(
                    files, out, "--method", "backprojection", "--scale", str(scale), "--iterations", "3"
                )
                == 0
            )
        err = capsys.readouterr().err
        assert "--iterations not used by --method backprojection (its options: --scale); ignored" in err
        one, two = (read_volume(out) for out in outs)
        assert one.metadata["method"] == "backprojection" and two.metadata["scale"] == 2.0
        torch.testing.assert_close(two.data, 2.0 * one.data, rtol=1e-5, atol=1e-6 * float(one.data.max()))
        truth = read_volume(files["truth"]).data
        assert float(ncc(truth, one.data)) > 0.1  # measured 0.22; a constant volume scores 0
    with pytest.raises(SystemExit):  # gone from the choices once unregistered
        _reconstruct(files, tmp_path / "gone.tif", "--method", "backprojection")
    assert "invalid choice: 'backprojection'" in capsys.readouterr().err


def test_a_method_option_out_of_bounds_names_the_flag(files, tmp_path, capsys):
    capsys.readouterr()
    assert _reconstruct(files, tmp_path / "w.tif", "--method", "wiener", "--snr", "0") == 2
    assert "--snr must be a finite number > 0; got 0.0. Fix: e.g. --snr 100.0" in capsys.readouterr().err
    assert not (tmp_path / "w.tif").exists()


def test_a_method_that_does_not_run_on_the_device_is_refused(files, tmp_path, capsys):
    from dataclasses import replace

    from tests import toy_method

    with toy_method.registered():
        registry.register(replace(registry.get("backprojection"), devices=("cuda",)), overwrite=True)
        capsys.readouterr()
        assert _reconstruct(files, tmp_path / "bp.tif", "--method", "backprojection") == 2
    assert (
        "--method backprojection runs on cuda; got --device cpu. Fix: --device cuda."
        in capsys.readouterr().err
    )
    assert not (tmp_path / "bp.tif").exists()
