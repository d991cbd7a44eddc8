"""``lfm-studio reconstruct --out NAME.ome.zarr``: the same volumes as the TIFF path, resume, refusals."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import tifffile
import torch

if any(importlib.util.find_spec(name) is None for name in ("dask", "distributed", "zarr", "ome_zarr")):
    pytest.skip("the scale extra is not installed", allow_module_level=True)

import zarr

from lfm_studio import cli
from lfm_studio.engine.design import load_preset
from lfm_studio.engine.io import read_volume, write_psf_stack
from lfm_studio.engine.simulation import imaging_setup, simulate_psf

FRAMES = 6
COMMON = ["--iterations", "3", "--baseline", "100", "--gain", "2", "--read-noise", "1.5"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A 3-depth FLFM PSF stack cropped to 128 x 128 px and 6 noisy camera frames (ADU, seeded)."""
    folder = tmp_path_factory.mktemp("video_cli")
    design = load_preset("flfm_guo2019")
    design = design.updated(depths=type(design.depths)(depth_range_um=(-20.0, 20.0), depth_step_um=20.0))
    stack = simulate_psf(design, crop=128, dtype="float32")
    psf = write_psf_stack(folder / "psf.tif", stack)
    setup = imaging_setup(stack)
    volume = (torch.rand(setup.volume_shape, generator=torch.Generator().manual_seed(5)) > 0.9995).float()
    expected = setup.projector.forward(volume).numpy()
    expected = expected * (1500.0 / expected.max())
    frames = np.stack([100 + 2 * np.random.default_rng(s).poisson(expected) for s in range(FRAMES)])
    image = folder / "frames.tif"
    tifffile.imwrite(image, frames.astype(np.uint16))
    return {"psf": psf, "image": image, "folder": folder}


def _run(files, out, *extra: str) -> int:
    argv = ["reconstruct", "--psf", str(files["psf"]), "--image", str(files["image"]), "--out", str(out)]
    return cli.main([*argv, *COMMON, *extra])


def test_video_equals_the_tiff_path_and_resumes(files, tmp_path, capsys):
    tiff = tmp_path / "volume.tif"
    assert _run(files, tiff) == 0
    reference = read_volume(tiff).data.numpy()
    store = tmp_path / "run.ome.zarr"
    assert _run(files, store, "--chunk-frames", "2", "--workers", "1") == 0
    assert "6 computed now" in capsys.readouterr().out
    level0 = zarr.open_group(str(store), mode="r")["0"]
    assert level0.shape == reference.shape
    np.testing.assert_allclose(level0[:], reference, rtol=1e-5, atol=1e-5 * float(np.abs(reference).max()))

    (store / "lfm_studio_status" / "chunk_000002.json").unlink()  # as if killed before the last record
    assert _run(files, store, "--chunk-frames", "2") == 3  # exists: refused without --resume
    assert "--resume" in capsys.readouterr().err
    assert _run(files, store, "--chunk-frames", "2", "--resume") == 0
    assert "2 computed now, 4 done before" in capsys.readouterr().out
    np.testing.assert_allclose(level0[:], reference, rtol=1e-5, atol=1e-5 * float(np.abs(reference).max()))


def test_a_nan_frame_exits_5_and_keeps_the_others(files, tmp_path, capsys):
    frames = tifffile.imread(files["image"]).astype(np.float32)
    frames[3, 10, 10] = np.nan
    bad = tmp_path / "nan.tif"
    tifffile.imwrite(bad, frames)
    out = tmp_path / "run.ome.zarr"
    argv = ["reconstruct", "--psf", str(files["psf"]), "--image", str(bad), "--out", str(out)]
    assert cli.main([*argv, *COMMON]) == 5
    err = capsys.readouterr().err
    assert "frame 3" in err and "NaN" in err
    level0 = zarr.open_group(str(out), mode="r")["0"][:]
    assert not level0[3].any() and all(level0[t].any() for t in (0, 1, 2, 4, 5))
    assert "--resume (only the failed frames are computed again)" in err


def test_resume_recomputes_a_frame_that_failed_once_the_file_is_fixed(files, tmp_path, capsys):
    frames = tifffile.imread(files["image"]).astype(np.float32)
    broken = frames.copy()
    broken[3, 10, 10] = np.nan
    image = tmp_path / "frames.tif"
    tifffile.imwrite(image, broken)
    out = tmp_path / "run.ome.zarr"
    argv = ["reconstruct", "--psf", str(files["psf"]), "--image", str(image), *COMMON]
    assert cli.main([*argv, "--out", str(out), "--chunk-frames", "2"]) == 5
    capsys.readouterr()
    tifffile.imwrite(image, frames)  # the frame repaired in place: same file, same shape
    assert cli.main([*argv, "--out", str(out), "--chunk-frames", "2", "--resume"]) == 0
    captured = capsys.readouterr()
    assert "1 computed now, 5 done before" in captured.out
    assert (
        "Frame(s) [3] had failed in an earlier run and were computed again: 1 reconstructed" in captured.err
    )
    clean = tmp_path / "clean.ome.zarr"
    assert cli.main([*argv, "--out", str(clean), "--chunk-frames", "2"]) == 0
    resumed, expected = (zarr.open_group(str(path), mode="r")["0"][:] for path in (out, clean))
    np.testing.assert_allclose(resumed, expected, rtol=1e-6, atol=1e-6 * float(np.abs(expected).max()))


@pytest.mark.parametrize(
    ("extra", "named"),
    [
        (["--workers", "0"], "workers"),
        (["--measured"], "--measured"),
        (["--chunk-frames", "0"], "chunk_frames"),
    ],
)
def test_bad_video_options_exit_2_naming_them(files, tmp_path, capsys, extra, named):
    assert _run(files, tmp_path / "run.ome.zarr", *extra) == 2
    assert named in capsys.readouterr().err
    assert not (tmp_path / "run.ome.zarr").exists()


def test_quantum_efficiency_scales_the_photons_in_the_tiff_and_video_paths(files, tmp_path, capsys):
    plain, halved = tmp_path / "plain.tif", tmp_path / "qe.tif"
    assert _run(files, plain) == 0 and _run(files, halved, "--quantum-efficiency", "0.5") == 0
    volume, with_qe = read_volume(plain).data.numpy(), read_volume(halved).data.numpy()
    # photons = electrons / QE, and the noise floor (the background) likewise: the volume doubles.
    np.testing.assert_allclose(with_qe, 2 * volume, rtol=1e-4, atol=1e-4 * float(np.abs(volume).max()))
    store = tmp_path / "qe.ome.zarr"
    assert _run(files, store, "--quantum-efficiency", "0.5", "--workers", "1") == 0
    video = zarr.open_group(str(store), mode="r")["0"][:]
    np.testing.assert_allclose(video, with_qe, rtol=1e-5, atol=1e-5 * float(np.abs(with_qe).max()))


@pytest.mark.parametrize("value", ["0", "1.5", "80", "nan", "high"])
def test_a_quantum_efficiency_outside_0_1_exits_2_naming_it(files, tmp_path, capsys, value):
    with pytest.raises(SystemExit) as exit_:
        _run(files, tmp_path / "v.tif", "--quantum-efficiency", value)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert (
        "--quantum-efficiency must be a fraction 0 < QE <= 1" in err and repr(value) in err and "Fix" in err
    )
    assert not (tmp_path / "v.tif").exists()


def test_ctrl_c_says_how_many_frames_the_store_keeps_and_to_resume(files, tmp_path, capsys, monkeypatch):
    from lfm_studio.engine.batch import video

    process = video.process_chunk
    chunks = []

    def interrupted_at_the_second_chunk(task):
        chunks.append(task)
        if len(chunks) == 2:
            raise KeyboardInterrupt  # Ctrl+C while frames 2-3 are reconstructed
        return process(task)

    monkeypatch.setattr(video, "process_chunk", interrupted_at_the_second_chunk)
    store = tmp_path / "run.ome.zarr"
    assert _run(files, store, "--chunk-frames", "2", "--workers", "1") == 130
    err = capsys.readouterr().err
    assert f"interrupted; 2 of {FRAMES} frames are in {store}" in err and "no output was written" not in err
    assert "Fix: run the same command with --resume" in err
    monkeypatch.setattr(video, "process_chunk", process)
    assert _run(files, store, "--chunk-frames", "2", "--workers", "1", "--resume") == 0
    assert "4 computed now, 2 done before" in capsys.readouterr().out


def test_ctrl_c_of_an_overwrite_keeps_the_previous_store_and_says_so(files, tmp_path, capsys, monkeypatch):
    from lfm_studio.engine.batch import video

    store = tmp_path / "run.ome.zarr"
    assert _run(files, store, "--chunk-frames", "2") == 0
    before = {p: p.read_bytes() for p in sorted(store.rglob("*")) if p.is_file()}
    process = video.process_chunk
    chunks = []

    def interrupted_at_the_second_chunk(task):
        chunks.append(task)
        if len(chunks) == 2:
            raise KeyboardInterrupt
        return process(task)

    monkeypatch.setattr(video, "process_chunk", interrupted_at_the_second_chunk)
    capsys.readouterr()
    assert _run(files, store, "--chunk-frames", "2", "--overwrite") == 130
    err = capsys.readouterr().err
    assert f"interrupted; the previous store {store} is unchanged" in err and "--resume" not in err
    assert {p: p.read_bytes() for p in sorted(store.rglob("*")) if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.ome.zarr"]
