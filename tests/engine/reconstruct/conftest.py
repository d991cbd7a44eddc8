"""Small Fourier (FLFM) and conventional (10x) systems shared by the reconstruction tests.

PSFs are simulated once per session (about 1 s each): a 256 x 256 px FLFM camera with
5 depths 10 um apart (volume 5 x 93 x 93; the sensor cuts the outer sub-images), and a
10x/0.3 conventional LFM on 6 x 6 lenslets with 3 depths 20 um apart (volume 3 x 30 x 30,
image 114 x 114).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import pytest
import torch

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.operators import ShiftInvariantProjector
from lfm_studio.engine.phantoms import beads
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.simulation import ImagingSetup, imaging_setup, simulate_psf
from lfm_studio.engine.systems.conventional_psf import lattice_projector


@dataclass(frozen=True)
class System:
    """A setup in float32 and float64, the PSF stack it came from and its design."""

    setup: ImagingSetup
    setup64: ImagingSetup
    design: object
    stack: PSFStack


def _shrink(name: str, pixels: int, depth_range_um: tuple[float, float], step_um: float):
    design = load_preset(name)
    camera = type(design.camera)(**{**design.camera.model_dump(), "pixel_count": (pixels, pixels)})
    depths = type(design.depths)(depth_range_um=depth_range_um, depth_step_um=step_um)
    return design.updated(camera=camera, depths=depths)


def make_fourier() -> System:
    with warnings.catch_warnings():  # the 256 px sensor cuts the outer sub-images: expected here
        warnings.simplefilter("ignore", DesignWarning)
        design = _shrink("flfm_guo2019", 256, (-20.0, 20.0), 10.0)
        stack = simulate_psf(design)
    setup = imaging_setup(stack)
    projector64 = ShiftInvariantProjector(stack.data.double(), setup.volume_shape[1:])
    setup64 = ImagingSetup(projector64, setup.volume_shape, setup.voxel_size)
    return System(setup, setup64, design, stack)


def make_conventional() -> System:
    design = _shrink("lfm_10x_na03", 130, (-20.0, 20.0), 20.0)
    stack = simulate_psf(design, dtype="float64")
    setup64 = imaging_setup(stack)
    projector32 = lattice_projector(stack.to(dtype=torch.float32))
    setup = ImagingSetup(projector32, setup64.volume_shape, setup64.voxel_size)
    return System(setup, setup64, design, stack)


@pytest.fixture(scope="package", autouse=True)
def _one_torch_thread():
    """Run this package's small FFTs on one thread, restoring the setting afterwards.

    Measured here with other jobs on the 2 cores: an RL iteration of the FLFM system took
    18-60 ms on one thread and 280-500 ms on two (docs/platform.md: torch threads thrash under load).
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def fourier() -> System:
    return make_fourier()


@pytest.fixture(scope="session")
def conventional() -> System:
    return make_conventional()


def bead_phantom(setup: ImagingSetup, *, count: int, seed: int, intensity: float = 1000.0):
    """Point beads anywhere in the volume, each pair at least 8 voxels apart laterally or 2 axially."""
    _, dy, dx = setup.voxel_size
    phantom = beads(
        setup.volume_shape,
        count=count,
        voxel_size=setup.voxel_size,
        seed=seed,
        intensity=intensity,
        margin=0.0,
        min_separation=8 * max(dy, dx),
    )
    idx = phantom.indices
    for i in range(count):
        for j in range(i):
            lateral = float((idx[i, 1:] - idx[j, 1:]).abs().max())
            axial = float((idx[i, 0] - idx[j, 0]).abs())
            assert lateral >= 8 or axial >= 2, f"seed {seed} gives beads too close: {idx.tolist()}"
    return phantom


def psnr(truth: torch.Tensor, estimate: torch.Tensor) -> float:
    """PSNR in dB with the truth's maximum as data range (float64)."""
    t, e = truth.double().cpu(), estimate.double().cpu()
    mse = float(((t - e) ** 2).mean())
    return 10.0 * torch.log10(torch.tensor(float(t.max()) ** 2 / mse)).item()


def ssim3d(truth: torch.Tensor, estimate: torch.Tensor, sigma: float = 1.5) -> float:
    """Mean SSIM over the volume (Wang et al. 2004): Gaussian window sigma 1.5 voxels, K1 0.01, K2 0.03,
    data range = truth max; the window is separable and truncated at 3 sigma."""
    t, e = truth.double().cpu()[None, None], estimate.double().cpu()[None, None]
    radius = int(3 * sigma)
    g = torch.exp(-0.5 * (torch.arange(-radius, radius + 1, dtype=torch.float64) / sigma) ** 2)
    g = g / g.sum()

    def blur(v: torch.Tensor) -> torch.Tensor:
        for dim in range(3):
            shape = [1, 1, 1, 1, 1]
            shape[2 + dim] = g.numel()
            pad = [0, 0] * 3
            pad[2 * (2 - dim)] = pad[2 * (2 - dim) + 1] = radius
            v = torch.nn.functional.conv3d(torch.nn.functional.pad(v, pad, mode="replicate"), g.view(shape))
        return v

    c1, c2 = (0.01 * float(t.max())) ** 2, (0.03 * float(t.max())) ** 2
    mt, me = blur(t), blur(e)
    vt, ve, cov = blur(t * t) - mt**2, blur(e * e) - me**2, blur(t * e) - mt * me
    index = ((2 * mt * me + c1) * (2 * cov + c2)) / ((mt**2 + me**2 + c1) * (vt + ve + c2))
    return float(index.mean())
