"""Hostile inputs to the CLI (issue 12): each ends in a named error with a fix, the documented exit
code, and no partial or replaced file."""

from __future__ import annotations

import json
import os
import tempfile

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio import cli
from lfm_studio.cli import main
from lfm_studio.cli.errors import BAD_INPUT, OUT_OF_MEMORY, OUTPUT_REFUSED, RESULT_REJECTED
from lfm_studio.engine.design import load_preset, save_design
from lfm_studio.engine.io import read_image, read_volume, write_image, write_volume


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Small Guo design (288 px, 3 depths), its PSF stack, a noisy ADU image of 3 beads and the truth."""
    folder = tmp_path_factory.mktemp("hostile")
    design = load_preset("flfm_guo2019")
    camera = type(design.camera)(**{**design.camera.model_dump(), "pixel_count": (288, 288)})
    paths = {name: folder / f"{name}.tif" for name in ("psf", "lf", "truth")}
    paths["design"] = folder / "small.json"
    save_design(design.updated(camera=camera), paths["design"])
    assert main(["simulate", str(paths["design"]), "--depths=-20:20:20", "--out", str(paths["psf"])]) == 0
    assert main(["image", str(paths["design"]), "--psf", str(paths["psf"]), "--count", "3", "--photons", "1e6",
                 "--seed", "1", "--out", str(paths["lf"]), "--truth", str(paths["truth"])]) == 0  # fmt: skip
    return paths


def _reconstruct(files, image, out, *extra: str) -> int:
    return main(["reconstruct", "--psf", str(files["psf"]), "--image", str(image), "--out", str(out),
                 "--iterations", "3", *extra])  # fmt: skip


def _refused(capsys, *parts: str) -> str:
    err = capsys.readouterr().err
    assert "error:" in err and "Traceback" not in err, err
    for part in parts:
        assert part in err, (part, err)
    return err


def _snapshot(folder) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


def test_output_equal_to_the_input_is_refused_even_with_overwrite(files, capsys):
    before = files["lf"].read_bytes()
    capsys.readouterr()
    assert _reconstruct(files, files["lf"], files["lf"], "--overwrite") == OUTPUT_REFUSED
    _refused(capsys, "is also an input of this run", "refused even with --overwrite", "Fix:")
    assert files["lf"].read_bytes() == before
    # the same through another spelling of the path, and for image --truth over its PSF
    other = files["lf"].parent / "." / files["lf"].name
    assert _reconstruct(files, files["lf"], other, "--overwrite") == OUTPUT_REFUSED
    design = str(files["design"])
    command = ["image", design, "--psf", str(files["psf"]), "--out", str(files["psf"].parent / "new.tif"),
               "--truth", str(files["psf"]), "--overwrite"]  # fmt: skip
    psf_before = files["psf"].read_bytes()
    assert main(command) == OUTPUT_REFUSED
    assert files["psf"].read_bytes() == psf_before and not (files["psf"].parent / "new.tif").exists()


def test_existing_outputs_are_kept_without_overwrite(files, tmp_path, capsys):
    truth = tmp_path / "truth.tif"
    truth.write_bytes(b"user data")
    command = ["image", str(files["design"]), "--psf", str(files["psf"]), "--count", "3",
               "--out", str(tmp_path / "lf.tif"), "--truth", str(truth)]  # fmt: skip
    capsys.readouterr()
    assert main(command) == OUTPUT_REFUSED
    _refused(capsys, f"{truth} exists", "--overwrite")
    assert truth.read_bytes() == b"user data" and sorted(p.name for p in tmp_path.iterdir()) == ["truth.tif"]
    # two outputs naming one file are refused too
    same = ["image", str(files["design"]), "--psf", str(files["psf"]), "--out", str(tmp_path / "a.tif"),
            "--truth", str(tmp_path / "a.tif")]  # fmt: skip
    assert main(same) == OUTPUT_REFUSED and not (tmp_path / "a.tif").exists()


def test_read_only_output_folder(files, tmp_path, monkeypatch, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        if os.access(locked, os.W_OK):  # root ignores permissions: make the check see what a user would
            real = os.access
            monkeypatch.setattr(
                os, "access", lambda p, mode: False if str(p) == str(locked) else real(p, mode)
            )
        capsys.readouterr()
        assert _reconstruct(files, files["lf"], locked / "vol.tif") == OUTPUT_REFUSED
        _refused(capsys, f"the folder {locked} is not writable", "Fix:")
        assert list(locked.iterdir()) == []
    finally:
        locked.chmod(0o755)


def test_permission_denied_while_writing_is_named_and_leaves_nothing(tmp_path, monkeypatch):
    from lfm_studio.engine.io import OutputError

    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "mkstemp", denied)
    with pytest.raises(OutputError, match=r"cannot write .*vol\.tif: the folder .* is not writable"):
        write_volume(tmp_path / "vol.tif", torch.ones(2, 3, 3), voxel_size=(1e-6,) * 3)
    assert list(tmp_path.iterdir()) == []


def test_full_disk_is_named_and_leaves_nothing(tmp_path, monkeypatch):
    import errno

    from lfm_studio.engine.io import OutputError

    def full(fh, *args, **kwargs):
        fh.write(b"II*\x00" + b"\x00" * 1024)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(tifffile, "imwrite", full)
    with pytest.raises(OutputError, match=r"cannot write .*vol\.tif: no space left .*Fix: free some space"):
        write_volume(tmp_path / "vol.tif", torch.ones(2, 3, 3), voxel_size=(1e-6,) * 3)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("interrupt", [RuntimeError("encoder crashed"), KeyboardInterrupt()])
def test_a_write_interrupted_midway_keeps_the_previous_file(files, tmp_path, monkeypatch, interrupt):
    out = tmp_path / "vol.tif"
    assert _reconstruct(files, files["lf"], out) == 0
    before = out.read_bytes()

    def half_then_fail(fh, *args, **kwargs):  # a crash (or Ctrl+C) in the middle of the data
        fh.write(b"II*\x00" + b"\x00" * 4096)
        raise interrupt

    monkeypatch.setattr(tifffile, "imwrite", half_then_fail)
    if isinstance(interrupt, KeyboardInterrupt):  # Ctrl+C: exit 130 and a message, no traceback
        assert _reconstruct(files, files["lf"], out, "--overwrite") == 130
    else:  # an unexpected error is a bug: it propagates (traceback, exit 1)
        with pytest.raises(type(interrupt)):
            _reconstruct(files, files["lf"], out, "--overwrite")
    assert out.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["vol.tif"]


def test_huge_sensor_design_is_refused_before_allocating(files, tmp_path, capsys):
    data = json.loads(files["design"].read_text())
    data["camera"]["pixel_count"] = [100000, 100000]
    huge = tmp_path / "huge.json"
    huge.write_text(json.dumps(data))
    capsys.readouterr()
    assert (
        main(["simulate", str(huge), "--depths=-20:20:10", "--out", str(tmp_path / "psf.tif")])
        == OUT_OF_MEMORY
    )
    err = _refused(capsys, "100000 x 100000 px sensor", "bytes", "camera.pixel_count")
    assert "Nothing was allocated" in err and list(tmp_path.iterdir()) == [huge]


def test_complex_image_is_refused(files, tmp_path, capsys):
    frame = read_image(files["lf"]).data.numpy().astype(np.complex64) * (1 + 1j)
    path = tmp_path / "complex.tif"
    tifffile.imwrite(path, frame)
    capsys.readouterr()
    assert _reconstruct(files, path, tmp_path / "vol.tif") == BAD_INPUT
    _refused(capsys, f"{path} holds complex data (complex64)", "Fix:")
    assert not (tmp_path / "vol.tif").exists()


@pytest.mark.parametrize("damage", ["truncated", "garbage"])
def test_truncated_or_corrupt_tiff_names_the_file(files, tmp_path, capsys, damage):
    data = files["lf"].read_bytes()
    path = tmp_path / "broken.tif"
    path.write_bytes(data[: len(data) // 2] if damage == "truncated" else os.urandom(4096))
    capsys.readouterr()
    assert _reconstruct(files, path, tmp_path / "vol.tif") == BAD_INPUT
    _refused(capsys, f"{path} is truncated or corrupt", "Fix:")
    assert not (tmp_path / "vol.tif").exists()


def test_nan_and_inf_pixels_are_refused(files, tmp_path, capsys):
    frame = read_image(files["lf"]).data.numpy().astype(np.float32)
    frame[5, 5], frame[6, 6] = np.nan, np.inf
    path = tmp_path / "nan.tif"
    tifffile.imwrite(path, frame, imagej=True, resolution=(1 / 6.5, 1 / 6.5), metadata={"unit": "um"})
    capsys.readouterr()
    assert _reconstruct(files, path, tmp_path / "vol.tif", "--baseline", "100", "--gain", "1") == BAD_INPUT
    _refused(capsys, f"{path} has 2 NaN/Inf pixel(s)", "Fix:")


def test_wrong_dimensionality_and_wrong_kind(files, tmp_path, capsys):
    four = tmp_path / "four.tif"
    tifffile.imwrite(four, np.ones((2, 3, 16, 16), np.float32), imagej=True, metadata={"axes": "TZYX"})
    capsys.readouterr()
    assert _reconstruct(files, four, tmp_path / "vol.tif") == BAD_INPUT
    _refused(capsys, "4-D series", "at most 3 dimensions", "Fix:")
    assert _reconstruct(files, files["truth"], tmp_path / "vol.tif") == BAD_INPUT  # a volume given as --image
    _refused(capsys, "holds an lfm_studio 'volume', not a 'image'")


def test_psf_and_image_pixel_sizes_must_match(files, tmp_path, capsys):
    image = read_image(files["lf"])
    binned = tmp_path / "binned.tif"
    write_image(binned, image.data, pixel_size=13e-6, metadata=image.metadata)
    capsys.readouterr()
    assert _reconstruct(files, binned, tmp_path / "vol.tif") == BAD_INPUT
    _refused(capsys, "has 13 um pixels but the PSF stack", "6.5 um", "Fix:")


def test_an_image_that_is_not_ours(files, tmp_path, capsys):
    """A plain camera TIFF (uint16, no metadata): --baseline/--gain/--read-noise reproduce the metadata
    result up to the unknown QE (RL is scale-equivariant); without them the baseline is estimated with
    a warning."""
    image = read_image(files["lf"])
    camera = image.metadata["camera"]
    plain = tmp_path / "camera.tif"
    tifffile.imwrite(plain, image.data.numpy().astype(np.uint16))
    ours, given, guessed = (tmp_path / f"{n}.tif" for n in ("ours", "given", "guessed"))
    assert _reconstruct(files, files["lf"], ours) == 0
    capsys.readouterr()
    options = ["--baseline", str(camera["baseline_adu"]), "--gain", str(camera["gain_adu_per_e"]),
               "--read-noise", str(camera["read_noise_e"])]  # fmt: skip
    assert _reconstruct(files, plain, given, *options) == 0
    err = capsys.readouterr().err
    assert "has no pixel size; taking the PSF's 6.5 um" in err and "estimated" not in err
    expected = read_volume(ours).data * camera["quantum_efficiency"]  # QE unknown for a foreign file: 1
    assert torch.allclose(read_volume(given).data, expected, rtol=1e-4, atol=1e-4 * float(expected.max()))
    assert _reconstruct(files, plain, guessed) == 0
    err = capsys.readouterr().err
    assert "warning:" in err and "estimated the baseline as" in err and "--baseline ADU" in err
    assert "--gain" in err
    volume, truth = read_volume(guessed), read_volume(files["truth"]).data
    assert volume.metadata["camera"]["source"] == "estimated"
    assert volume.metadata["units"] == "ADU above the baseline per voxel"
    assert float(np.corrcoef(truth.ravel(), volume.data.ravel())[0, 1]) > 0.3


def test_missing_design_key_and_corrupt_json(files, tmp_path, capsys):
    data = json.loads(files["design"].read_text())
    del data["camera"]["pixel_count"]
    missing = tmp_path / "missing.json"
    missing.write_text(json.dumps(data))
    corrupt = tmp_path / "corrupt.json"
    corrupt.write_text(files["design"].read_text()[:-20])
    capsys.readouterr()
    for design, parts in (
        (missing, ("the key 'camera.pixel_count' is missing", "Fix:")),
        (corrupt, (f"{corrupt} is not valid JSON", "Fix:")),
    ):
        assert main(["simulate", str(design), "--out", str(tmp_path / "psf.tif")]) == BAD_INPUT
        err = _refused(capsys, *parts)
        assert "errors.pydantic.dev" not in err
    assert not (tmp_path / "psf.tif").exists()


def test_a_rejected_reconstruction_writes_nothing(files, tmp_path, monkeypatch, capsys):
    from lfm_studio.engine.reconstruct import builtin_methods

    monkeypatch.setattr(
        builtin_methods, "richardson_lucy", lambda projector, frame, **kw: torch.zeros(projector.volume_shape)
    )
    capsys.readouterr()
    assert _reconstruct(files, files["lf"], tmp_path / "vol.tif") == RESULT_REJECTED
    _refused(capsys, "is all zero; it was not saved", "Likely causes", "baseline")
    assert list(tmp_path.iterdir()) == []


def test_background_above_the_data_is_a_named_error(files, tmp_path, capsys):
    capsys.readouterr()
    assert _reconstruct(files, files["lf"], tmp_path / "vol.tif", "--baseline", "60000") == BAD_INPUT
    _refused(capsys, "no signal above the background")
    assert list(tmp_path.iterdir()) == []


def test_exit_codes_are_documented_in_help(capsys):
    with pytest.raises(SystemExit) as caught:
        cli.main(["--help"])
    assert caught.value.code == 0
    out = capsys.readouterr().out
    for line in ("exit status:", f"{BAD_INPUT}    bad input", f"{OUTPUT_REFUSED}    output refused",
                 f"{OUT_OF_MEMORY}    not enough memory", f"{RESULT_REJECTED}    the reconstruction came out"):  # fmt: skip
        assert line in out
