"""Acceptance (issue 12): ``simulate -> image -> reconstruct`` with default flags gives a volume that
correlates with the truth and beats the all-zero volume's PSNR, on a Fourier and a conventional preset.

Only paths, a small depth range and a cropped sensor are given. Pearson correlation and PSNR are
computed here with numpy, independently of ``lfm_studio.engine.image_quality``; the floor is the PSNR of
the all-zero volume against the same truth (a sparse bead truth scores high for doing nothing).
"""

from __future__ import annotations

import numpy as np
import pytest

from lfm_studio.cli import main
from lfm_studio.engine.design import load_preset, save_design
from lfm_studio.engine.io import read_image, read_volume

CASES = {
    # preset: (sensor pixels, --depths): the crops of the other CLI tests (every sub-image / 6 x 6 lenslets)
    "flfm_guo2019": (288, "-20:20:10"),
    "lfm_10x_na03": (130, "-20:20:20"),
}


def _small_design(folder, preset: str, pixels: int):
    design = load_preset(preset)
    camera = type(design.camera)(**{**design.camera.model_dump(), "pixel_count": (pixels, pixels)})
    path = folder / f"{preset}.json"
    save_design(design.updated(camera=camera), path)
    return path


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a.ravel() - a.mean(), b.ravel() - b.mean()
    return float((a @ b) / np.sqrt((a @ a) * (b @ b)))


def psnr(truth: np.ndarray, estimate: np.ndarray) -> float:
    """PSNR in dB with the truth's range as the peak (no normalisation of the estimate)."""
    peak = truth.max() - truth.min()
    return float(10 * np.log10(peak**2 / np.mean((estimate - truth) ** 2)))


def _volume(path) -> np.ndarray:
    return read_volume(path).data.numpy().astype(np.float64)


@pytest.fixture(scope="module", params=list(CASES))
def flow(request, tmp_path_factory):
    """``simulate`` and ``image`` with default flags (a noise-free image) for one preset."""
    preset = request.param
    pixels, depths = CASES[preset]
    folder = tmp_path_factory.mktemp(preset)
    design = _small_design(folder, preset, pixels)
    paths = {name: folder / f"{name}.tif" for name in ("psf", "lf", "truth")}
    assert main(["simulate", str(design), "--depths", depths, "--out", str(paths["psf"])]) == 0
    assert main(["image", str(design), "--psf", str(paths["psf"]), "--out", str(paths["lf"]),
                 "--truth", str(paths["truth"])]) == 0  # fmt: skip
    return preset, design, paths


def _reconstruct(paths, out, *extra: str) -> np.ndarray:
    assert main(["reconstruct", "--psf", str(paths["psf"]), "--image", str(paths["lf"]), "--out", str(out),
                 *extra]) == 0  # fmt: skip
    return _volume(out)


def test_default_flow_reconstructs_the_truth(flow, tmp_path):
    preset, _, paths = flow
    truth = _volume(paths["truth"])
    volume = _reconstruct(paths, tmp_path / "vol.tif")
    assert volume.shape == truth.shape
    r, gain = pearson(truth, volume), psnr(truth, volume) - psnr(truth, np.zeros_like(truth))
    print(
        f"{preset} default flow (rl 30): Pearson {r:.3f}, PSNR {psnr(truth, volume):.2f} dB, +{gain:.2f} dB"
    )
    assert r >= 0.3 and gain >= 3.0
    # Same unit as the truth (photons per voxel): the totals agree without any normalisation.
    assert volume.sum() == pytest.approx(truth.sum(), rel=0.1)
    assert read_volume(tmp_path / "vol.tif").metadata["units"] == "photons per voxel"
    # The accelerated method on the same flow is not all zero (it was, before the camera round trip).
    fast = _reconstruct(paths, tmp_path / "fast.tif", "--method", "rl-accelerated")
    r_fast = pearson(truth, fast)
    print(
        f"{preset} rl-accelerated: Pearson {r_fast:.3f}, +{psnr(truth, fast) - psnr(truth, 0 * truth):.2f} dB"
    )
    assert fast.max() > 0 and r_fast >= 0.3


def test_readme_flow_with_camera_noise_needs_no_extra_flag(tmp_path_factory):
    """The README line (``--photons 1e6 --seed 1``): uint16 ADU with a 100 ADU baseline, reconstructed
    with no --background/--baseline flag (issue 12: Pearson 0.01 before)."""
    folder = tmp_path_factory.mktemp("readme")
    pixels, depths = CASES["flfm_guo2019"]
    design = _small_design(folder, "flfm_guo2019", pixels)
    psf, lf, truth_path = (folder / f"{n}.tif" for n in ("psf", "lf", "truth"))
    assert main(["simulate", str(design), f"--depths={depths}", "--out", str(psf)]) == 0
    assert main(["image", str(design), "--psf", str(psf), "--phantom", "beads", "--photons", "1e6", "--seed", "1",
                 "--out", str(lf), "--truth", str(truth_path)]) == 0  # fmt: skip
    image = read_image(lf)
    assert image.metadata["units"] == "ADU" and image.metadata["camera"]["baseline_adu"] == 100.0
    assert float(image.data.min()) < 100 < float(image.data.max())  # raw counts, baseline included
    for method in ("rl", "rl-accelerated"):
        out = folder / f"{method}.tif"
        assert main(["reconstruct", "--psf", str(psf), "--image", str(lf), "--out", str(out),
                     "--method", method]) == 0  # fmt: skip
        truth, volume = _volume(truth_path), _volume(out)
        r, gain = pearson(truth, volume), psnr(truth, volume) - psnr(truth, np.zeros_like(truth))
        print(f"README flow ({method}): Pearson {r:.3f}, PSNR gain over all-zero {gain:.2f} dB")
        assert r >= 0.3 and gain >= 3.0
