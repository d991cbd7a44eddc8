"""``lfm-studio reconstruct`` on a small conventional design: the TIFF path end to end.

A noisy camera image (``image --photons``, integer ADU with read noise) reconstructed with
Tikhonov keeps the truth's photons (``image --truth``, the independent reference); the clipped
frame of the old code gave 1.6x here. Wiener is refused with every method that takes the stack.
"""

from __future__ import annotations

import pytest

from lfm_studio import cli
from lfm_studio.engine.design import load_preset, save_design
from lfm_studio.engine.io import read_psf_stack, read_volume
from lfm_studio.engine.reconstruct import registry
from lfm_studio.engine.simulation import imaging_setup

#: sqrt(114^2 pixels) x 1.9 photons of read noise is 2.2 % of the image's 1e4 photons; 0.1 is ~4.5 sigma.
TOLERANCE = 0.1


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """10x/0.3 conventional LFM on 6 x 6 lenslets, 3 depths; its patterns, a noisy image of 3 beads, the truth."""
    folder = tmp_path_factory.mktemp("conventional_cli")
    design = load_preset("lfm_10x_na03")
    camera = type(design.camera)(**{**design.camera.model_dump(), "pixel_count": (130, 130)})
    small = design.updated(
        camera=camera, depths=type(design.depths)(depth_range_um=(-20.0, 20.0), depth_step_um=20.0)
    )
    paths = {name: folder / f"{name}.tif" for name in ("psf", "lf", "truth")}
    paths["design"] = folder / "conventional.json"
    save_design(small, paths["design"])
    assert cli.main(["simulate", str(paths["design"]), "--out", str(paths["psf"])]) == 0
    image = ["image", str(paths["design"]), "--psf", str(paths["psf"]), "--count", "3", "--photons", "1e4"]
    assert cli.main([*image, "--seed", "0", "--out", str(paths["lf"]), "--truth", str(paths["truth"])]) == 0
    return paths


def _reconstruct(files, out, method: str) -> int:
    return cli.main(
        [
            "reconstruct",
            "--psf",
            str(files["psf"]),
            "--image",
            str(files["lf"]),
            "--out",
            str(out),
            "--method",
            method,
        ]
    )


def test_tikhonov_on_a_noisy_camera_image_keeps_the_truths_photons(files, tmp_path):
    out = tmp_path / "tikhonov.tif"
    assert _reconstruct(files, out, "tikhonov") == 0
    volume, truth = read_volume(out).data.double(), read_volume(files["truth"]).data.double()
    assert float(volume.sum() / truth.sum()) == pytest.approx(1.0, abs=TOLERANCE)


def test_wiener_is_refused_with_every_method_that_takes_the_stack(files, tmp_path, capsys):
    assert _reconstruct(files, tmp_path / "wiener.tif", "wiener") == 2
    message = capsys.readouterr().err
    projector = imaging_setup(read_psf_stack(files["psf"])).projector
    takers = [m.name for m in registry.methods() if m.supports(projector)]
    assert "tikhonov" in takers and "wiener" not in takers
    assert f"Fix: use --method {', '.join(takers[:-1])} or {takers[-1]}." in message
    assert not (tmp_path / "wiener.tif").exists()
