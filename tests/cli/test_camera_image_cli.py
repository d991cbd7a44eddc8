"""``lfm-studio image`` writes what a camera writes: uint16 ADU with its camera in the metadata, the
truth in photons per voxel, and the noise-free expected image only when asked for."""

from __future__ import annotations

import re

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio.cli import main
from lfm_studio.engine.design import load_preset, save_design
from lfm_studio.engine.io import read_image, read_psf_stack, read_volume
from lfm_studio.engine.simulation import imaging_setup


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    folder = tmp_path_factory.mktemp("camera_image")
    design = load_preset("flfm_guo2019")
    camera = {**design.camera.model_dump(), "pixel_count": (288, 288), "bit_depth": 12, "gain_adu_per_e": 2.0}
    path = folder / "small.json"
    save_design(design.updated(camera=type(design.camera)(**camera)), path)
    psf = folder / "psf.tif"
    assert main(["simulate", str(path), "--depths=-20:20:20", "--out", str(psf)]) == 0
    return folder, path, psf


def _image(simulated, name: str, *extra: str) -> dict:
    folder, design, psf = simulated
    paths = {key: folder / f"{name}_{key}.tif" for key in ("lf", "truth", "expected")}
    command = ["image", str(design), "--psf", str(psf), "--count", "3", "--seed", "2", "--out", str(paths["lf"]),
               "--truth", str(paths["truth"]), *extra]  # fmt: skip
    assert main(command) == 0
    return paths


def test_camera_image_is_uint16_adu_with_the_camera_recorded(simulated):
    paths = _image(
        simulated, "noisy", "--photons", "2e5", "--expected", str(simulated[0] / "noisy_expected.tif")
    )
    with tifffile.TiffFile(paths["lf"]) as tif:
        assert tif.series[0].dtype == np.uint16
    image = read_image(paths["lf"])
    camera = image.metadata["camera"]
    assert image.metadata["units"] == "ADU"
    assert camera == {
        "baseline_adu": 100.0, "gain_adu_per_e": 2.0, "quantum_efficiency": camera["quantum_efficiency"],
        "read_noise_e": camera["read_noise_e"], "bit_depth": 12, "full_well_e": camera["full_well_e"],
        "photons": 2e5, "seed": 2,
    }  # fmt: skip
    data = image.data.double()
    assert float(data.max()) <= 4095 and torch.equal(data, data.round())  # 12-bit integers
    # The expected image is the mean the counts scatter around: baseline + gain QE photons in total.
    expected = read_image(paths["expected"]).data.double()
    qe = camera["quantum_efficiency"]
    assert float((expected - 100.0).sum()) == pytest.approx(2.0 * qe * 2e5, rel=1e-4)
    assert float((data - 100.0).sum()) == pytest.approx(float((expected - 100.0).sum()), rel=0.02)
    # Truth in photons per voxel: projected, it gives the photons reaching the camera (2e5 in all).
    truth = read_volume(paths["truth"])
    assert truth.metadata["units"] == "photons per voxel"
    projector = imaging_setup(read_psf_stack(simulated[2])).projector
    photons = projector.forward(truth.data).clamp_min(0)
    assert float(photons.sum()) == pytest.approx(2e5, rel=1e-4)
    assert torch.allclose((photons * 2.0 * qe + 100.0).double(), expected, rtol=1e-4, atol=1e-3)


def test_expected_image_only_on_request_and_noise_free_default(simulated):
    folder = simulated[0]
    paths = _image(simulated, "clean")
    assert not paths["expected"].exists()
    image = read_image(paths["lf"])
    assert image.metadata["units"] == "photons" and image.metadata["camera"] is None
    with tifffile.TiffFile(paths["lf"]) as tif:
        assert tif.series[0].dtype == np.float32
    assert sorted(p.name for p in folder.iterdir() if p.name.startswith("clean")) == [
        "clean_lf.tif",
        "clean_truth.tif",
    ]


@pytest.mark.filterwarnings(
    "always::lfm_studio.engine.optics.camera.SaturationWarning"
)  # shown as a CLI note
def test_saturated_pixels_clip_at_the_bit_depth(simulated, capsys):
    paths = _image(simulated, "bright", "--photons", "1e9")
    assert re.search(
        r"lfm-studio image: warning: photons=1e\+09 saturates the camera: \d+ of \d+ pixels .*"
        r"\(the 12-bit ADC's top, 4095 ADU\).*Fix: photons <= ",
        capsys.readouterr().err,
    )
    data = read_image(paths["lf"]).data
    assert float(data.max()) == 4095.0  # 2^12 - 1: a 12-bit ADC saturates (the full well clips first)
