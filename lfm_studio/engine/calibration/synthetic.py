"""Synthetic radiometry and dark frames with known truth, for tests and benchmarks.

A radiometry frame is the image of a uniform fluorescent slide through the MLA: behind
each lenslet the camera sees the objective's back aperture, a bright disk of diameter
``2 f_lenslet tan(asin(NA / M))`` (see :func:`~lfm_studio.engine.calibration.nominal.nominal_grid`).
Disks are rendered with an area-coverage edge (a pixel at distance ``r`` from the disk
centre is covered ``clip(R - r + 1/2, 0, 1)``), multiplied by a smooth vignetting
``1 - v (rho / rho_max)^2``, turned into photo-electrons with Poisson noise, plus
Gaussian read noise, a dark offset (ADU) and hot pixels. Same seed, same frames.

:func:`forward_model_frames` makes the same kind of frames from the wave-optics forward
model instead of the disk renderer: a fluorescent plane at focus imaged by a conventional
design on its own lattice, shown through a raw geometry by
:func:`~lfm_studio.engine.calibration.rectify.unrectify`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from lfm_studio.engine.calibration.lattice import LensletLattice
from lfm_studio.engine.calibration.nominal import nominal_grid, nominal_sub_images
from lfm_studio.engine.calibration.rectify import unrectify
from lfm_studio.engine.design import Design, load_preset
from lfm_studio.engine.simulation import imaging_setup, simulate_psf


@dataclass(frozen=True)
class SyntheticFrames:
    """A synthetic radiometry frame, its dark frame and the truth they were made from.

    Attributes
    ----------
    radiometry, dark : (Y, X) float64 ADU.
    clean : (Y, X) noise-free radiometry in photo-electrons before vignetting.
    vignetting : (Y, X) the multiplicative vignetting map applied.
    hot : (Y, X) bool, the hot pixels.
    lattice : the true lenslet lattice.
    disk_diameter : px.
    """

    radiometry: torch.Tensor
    dark: torch.Tensor
    clean: torch.Tensor
    vignetting: torch.Tensor
    hot: torch.Tensor
    lattice: LensletLattice
    disk_diameter: float


def disk_pattern(shape: tuple[int, int], lattice: LensletLattice, disk_diameter: float) -> torch.Tensor:
    """Fraction ``(Y, X)`` of each pixel covered by the lenslet disks (area-coverage edge), in [0, 1]."""
    ny, nx = shape
    yy, xx = torch.meshgrid(
        torch.arange(ny, dtype=torch.float64), torch.arange(nx, dtype=torch.float64), indexing="ij"
    )
    points = torch.stack((yy, xx), dim=-1)
    ij = lattice.lattice_coordinates(points)
    nearest = lattice.centres(ij.round())
    r = torch.linalg.vector_norm(points - nearest, dim=-1)
    return (0.5 * disk_diameter - r + 0.5).clamp(0.0, 1.0)


def radial_vignetting(shape: tuple[int, int], strength: float) -> torch.Tensor:
    """``1 - strength (rho / rho_max)^2`` over the frame, rho from the frame centre."""
    ny, nx = shape
    yy, xx = torch.meshgrid(
        torch.arange(ny, dtype=torch.float64) - (ny - 1) / 2,
        torch.arange(nx, dtype=torch.float64) - (nx - 1) / 2,
        indexing="ij",
    )
    rho2 = (yy**2 + xx**2) / (((ny - 1) / 2) ** 2 + ((nx - 1) / 2) ** 2)
    return 1.0 - strength * rho2


def synthetic_frames(
    shape: tuple[int, int],
    lattice: LensletLattice,
    *,
    disk_diameter: float,
    photons: float = 2000.0,
    vignetting: float = 0.3,
    baseline_adu: float = 100.0,
    read_noise_e: float = 1.5,
    gain_adu_per_e: float = 1.0,
    hot_fraction: float = 1e-3,
    hot_adu: float = 3000.0,
    seed: int = 0,
) -> SyntheticFrames:
    """Radiometry and dark frames of a uniform slide seen through ``lattice``.

    Parameters
    ----------
    shape : (Y, X) frame size, px.
    lattice : the lenslet lattice (true pitch, rotation, offset).
    disk_diameter : diameter of each lenslet's back-aperture disk, px.
    photons : photo-electrons per fully covered pixel at the frame centre.
    vignetting : strength ``v`` of ``1 - v (rho / rho_max)^2``.
    baseline_adu : dark offset, ADU.
    read_noise_e : Gaussian read noise, electrons rms.
    gain_adu_per_e : ADU per electron.
    hot_fraction : fraction of hot pixels (they add ``hot_adu`` to both frames).
    seed : random seed.
    """
    clean = photons * disk_pattern(shape, lattice, disk_diameter)
    vig = radial_vignetting(shape, vignetting)
    radiometry, dark, hot = expose(
        clean * vig,
        baseline_adu=baseline_adu,
        read_noise_e=read_noise_e,
        gain_adu_per_e=gain_adu_per_e,
        hot_fraction=hot_fraction,
        hot_adu=hot_adu,
        seed=seed,
    )
    return SyntheticFrames(
        radiometry=radiometry,
        dark=dark,
        clean=clean,
        vignetting=vig,
        hot=hot,
        lattice=lattice,
        disk_diameter=float(disk_diameter),
    )


def forward_model_frames(
    shape: tuple[int, int],
    lattice: LensletLattice,
    *,
    lenslets: int = 23,
    design: Design | None = None,
    photons: float = 2000.0,
    vignetting: float = 0.3,
    seed: int = 0,
) -> SyntheticFrames:
    """Radiometry and dark frames of a fluorescent plane at focus, from the conventional forward model.

    ``design`` (default ``lfm_10x_na03``) on a camera of ``lenslets x lenslets`` lenslets,
    one depth (0, the focal plane), images a uniform plane on its own lattice of ``n`` (odd)
    pixels per lenslet, lenslet ``k`` on pixels ``k n .. k n + n - 1`` (its axis on pixel
    ``k n + (n - 1) / 2``, the rectified-pixel convention of :func:`unrectify`).
    :func:`unrectify` puts that lattice's lenslet block ``(-(lenslets // 2), lenslets, ...)``
    on ``lattice`` of a raw frame of ``shape``, so ``lattice`` is the true lenslet lattice;
    light outside the block is 0 (a dark rim). The frame is scaled to ``photons`` at its
    brightest pixel, then vignetted and exposed as in :func:`synthetic_frames` (100 ADU dark
    offset, 1.5 e- read noise, gain 1, 0.1 % hot pixels of 3000 ADU). ``clean`` is the
    unvignetted photo-electron image; ``disk_diameter`` the design's back-aperture disk as a
    fraction of its pitch, times the mean raw pitch.
    """
    base = load_preset("lfm_10x_na03") if design is None else design
    ratio = nominal_grid(base).pitch  # camera pixels per lenslet
    side = math.ceil(lenslets * ratio)  # the sensor covers ``lenslets`` whole lenslets
    model = base.updated(
        camera={**base.camera.model_dump(), "pixel_count": (side, side)},
        depths={"depth_range_um": (0.0, 0.0), "depth_step_um": 1.0},
    )
    setup = imaging_setup(simulate_psf(model))
    plane = torch.ones(setup.volume_shape)
    image = setup.projector.forward(plane).clamp_min(0.0).double()
    n = nominal_grid(model).pixels_per_lenslet
    if tuple(image.shape) != (lenslets * n, lenslets * n):
        raise ValueError(
            f"the forward model imaged {tuple(image.shape)} px, not {lenslets} x {lenslets} lenslets of {n} px."
        )
    block = (-(lenslets // 2), lenslets, -(lenslets // 2), lenslets)
    raw = unrectify(image, lattice, block, shape)
    clean = raw * (photons / float(raw.max()))
    vig = radial_vignetting(shape, vignetting)
    radiometry, dark, hot = expose(
        clean * vig,
        baseline_adu=100.0,
        read_noise_e=1.5,
        gain_adu_per_e=1.0,
        hot_fraction=1e-3,
        hot_adu=3000.0,
        seed=seed,
    )
    fraction = nominal_grid(model).disk_diameter / ratio
    return SyntheticFrames(
        radiometry=radiometry,
        dark=dark,
        clean=clean,
        vignetting=vig,
        hot=hot,
        lattice=lattice,
        disk_diameter=fraction * sum(lattice.pitch) / 2,
    )


def expose(
    electrons_mean: torch.Tensor,
    *,
    baseline_adu: float,
    read_noise_e: float,
    gain_adu_per_e: float,
    hot_fraction: float,
    hot_adu: float,
    seed: int,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Radiometry and dark frames (ADU) and the hot-pixel mask for mean photo-electrons (Y, X).

    Poisson shot noise, Gaussian read noise (electrons rms), gain, a dark offset, and hot
    pixels that add ``hot_adu`` to both frames (they are a property of the sensor).
    """
    shape = tuple(electrons_mean.shape)
    generator = torch.Generator().manual_seed(int(seed))
    electrons = torch.poisson(electrons_mean.to(torch.float64), generator=generator)
    hot = torch.rand(shape, generator=generator, dtype=torch.float64) < hot_fraction

    def readout(signal: torch.Tensor) -> torch.Tensor:
        noise = read_noise_e * torch.randn(shape, generator=generator, dtype=torch.float64)
        return gain_adu_per_e * (signal + noise) + baseline_adu + hot_adu * hot

    return readout(electrons), readout(torch.zeros(shape, dtype=torch.float64)), hot


def sub_image_pattern(
    shape: tuple[int, int], centres: torch.Tensor, diameter: float, gains: torch.Tensor | None = None
) -> torch.Tensor:
    """Coverage (Y, X) in [0, 1] of Fourier-LFM sub-images: disks of ``diameter`` px at ``centres`` (L, 2).

    ``gains`` (L,) multiplies each sub-image's disk (a per-sub-image vignetting); default 1.
    """
    ny, nx = shape
    yy = torch.arange(ny, dtype=torch.float64)[:, None]
    xx = torch.arange(nx, dtype=torch.float64)[None, :]
    out = torch.zeros(shape, dtype=torch.float64)
    factors = [1.0] * len(centres) if gains is None else [float(g) for g in gains]
    for (cy, cx), factor in zip(centres.tolist(), factors, strict=True):
        r = torch.sqrt((yy - cy) ** 2 + (xx - cx) ** 2)
        out = torch.maximum(out, factor * (0.5 * diameter - r + 0.5).clamp(0.0, 1.0))
    return out


def conventional_design_for(
    pitch_px: float, frame_shape: tuple[int, int], *, disk_fraction: float = 0.9
) -> Design:
    """The ``lfm_10x_na03`` preset with an MLA of ``pitch_px`` sensor pixels and a ``frame_shape`` camera.

    The lenslet focal length (and the MLA-to-camera distance) is set so that the
    back-aperture disk is ``disk_fraction`` of the pitch, as in a real, slightly
    under-filled f-number match.
    """
    base = load_preset("lfm_10x_na03")
    pitch_um = pitch_px * base.camera.pixel_pitch_um
    sin_image = base.objective.numerical_aperture / base.objective.magnification
    focal_mm = disk_fraction * pitch_um / (2.0 * math.tan(math.asin(sin_image))) * 1e-3
    count = max(1, int(max(frame_shape) / pitch_px) + 2)
    mla = base.mla.model_copy(
        update={"pitch_um": pitch_um, "focal_length_mm": focal_mm, "shape": (count, count)}
    )
    camera = base.camera.model_copy(update={"pixel_count": tuple(frame_shape)})
    return base.updated(
        mla=mla.model_dump(), camera=camera.model_dump(), mla_to_camera_distance_mm=focal_mm, name="synthetic"
    )


def fourier_frames(
    design: Design,
    shape: tuple[int, int],
    *,
    rotation_deg: float = 0.0,
    scale: float = 1.0,
    shift: tuple[float, float] = (0.0, 0.0),
    jitter: float = 0.3,
    diameter_fraction: float = 0.97,
    photons: float = 1500.0,
    gains: torch.Tensor | None = None,
    seed: int = 0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Radiometry and dark frames (ADU) of a Fourier LFM, and the true sub-image centres (L, 2) px.

    The design's nominal sub-image centres are turned by ``rotation_deg`` about pixel
    ``(Y // 2, X // 2)``, scaled by ``scale``, shifted by ``shift`` (y, x) px and jittered by
    ``jitter`` px rms per axis; each sub-image is a disk ``diameter_fraction`` of the nominal
    diameter, with 30 % vignetting, noise, a 100 ADU dark offset and 0.1 % hot pixels.
    ``gains`` (L,) scales each sub-image's light (a per-sub-image vignetting; default 1).
    """
    nominal = nominal_sub_images(design, shape)
    centre = torch.tensor([shape[0] // 2, shape[1] // 2], dtype=torch.float64)
    a = math.radians(rotation_deg)
    turn = torch.tensor([[math.cos(a), math.sin(a)], [-math.sin(a), math.cos(a)]], dtype=torch.float64)
    noise = torch.randn(
        nominal.centres.shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64
    )
    truth = centre + scale * (nominal.centres - centre) @ turn.T + torch.tensor(shift, dtype=torch.float64)
    truth = truth + jitter * noise
    clean = photons * sub_image_pattern(shape, truth, diameter_fraction * nominal.diameter, gains)
    radiometry, dark, _ = expose(
        clean * radial_vignetting(shape, 0.3),
        baseline_adu=100.0,
        read_noise_e=1.5,
        gain_adu_per_e=1.0,
        hot_fraction=1e-3,
        hot_adu=3000.0,
        seed=seed,
    )
    return radiometry, dark, truth
