"""Small designs for the optimiser tests (crops of the shipped presets, few depths)."""

from __future__ import annotations

import warnings

import pytest
import torch

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.design.errors import DesignWarning


def small(name: str, pixels: int | None, depth_range_um: tuple[float, float], step_um: float):
    """Preset ``name`` with a ``pixels``-square sensor (None: unchanged) and a few depths."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        design = load_preset(name)
        changes = {"depths": type(design.depths)(depth_range_um=depth_range_um, depth_step_um=step_um)}
        if pixels is not None:
            changes["camera"] = type(design.camera)(
                **{**design.camera.model_dump(), "pixel_count": (pixels, pixels)}
            )
        return design.updated(**changes)


@pytest.fixture(scope="package")
def flfm():
    """FLFM (Guo 2019), 9 square lenslets of 600 um, full sensor for the constraints, 3 depths."""
    return small("flfm_guo2019", None, (-20.0, 20.0), 20.0)


@pytest.fixture(scope="package")
def xlfm():
    """XLFM (Cong 2017), 27 lenslets (per-lenslet PSF path), 3 depths."""
    return small("xlfm_cong2017", None, (-20.0, 20.0), 20.0)


@pytest.fixture(scope="package", autouse=True)
def _one_torch_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def tiny_flfm(lenslets: tuple[int, ...] = (1, 3, 4, 5, 7), pixels: int = 200):
    """The FLFM on a ``pixels``-square sensor with the plus of five central lenslets, 3 depths and
    one sub-sample per pixel: a fast differentiable case (about 0.1 s per PSF and gradient)."""
    design = small("flfm_guo2019", pixels, (-20.0, 20.0), 20.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        mla = type(design.mla)(
            lenslets=tuple(design.mla.lenslets[i] for i in lenslets), array_aperture_diameter_um=None
        )
        accuracy = type(design.accuracy)(
            **{**design.accuracy.model_dump(), "preset": "custom", "oversampling": 1}
        )
        return design.updated(mla=mla, accuracy=accuracy)


def tiny_conventional(pixels: int = 64):
    """The 10x/0.3 conventional LFM (125 um pitch, 1.875 mm lenslets) on a ``pixels``-square sensor
    (64: 3 x 3 lenslets of 19 px), 3 depths, 3 voxels per lenslet: about 0.3 s per float64 pattern
    stack and gradient."""
    design = small("lfm_10x_na03", pixels, (-20.0, 20.0), 20.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        accuracy = type(design.accuracy)(
            **{**design.accuracy.model_dump(), "preset": "custom", "voxels_per_lenslet": 3, "oversampling": 1}
        )
        return design.updated(accuracy=accuracy)
