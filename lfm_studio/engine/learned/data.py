"""Training data on the fly from the forward model: seeded phantoms imaged at a photon budget.

A sample is a phantom volume (beads, cell-like spheres, or either at random), scaled so that
its image holds a chosen number of photons, imaged through a projector with Poisson shot
noise and Gaussian read noise, in photons (counts already converted:
:func:`~lfm_studio.engine.io.counts_to_photons`); not clipped at 0, so the read noise stays
unbiased (models that need non-negative data clip it themselves). The truth is the phantom in photons per
voxel (the unit Richardson-Lucy reconstructs in).

Seeds: sample ``i`` of split ``s`` of a spec with seed ``S`` uses the seed
``S * 3_000_003 + SPLIT_OFFSET[s] + i`` with offsets 0, 1_000_001 and 2_000_002, so the
train, validation and test sets never share a phantom while ``i < 1_000_001``.

Optics mismatch (``optics_jitter`` > 0): the image of a sample may be formed through another
set-up than the one the model reconstructs with, a jittered design's
(:mod:`lfm_studio.engine.learned.mismatch`); the phantom, its seed, the photon budget and the
noise draws are those of the nominal sample with the same seed, only the optics differ.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Literal

import torch

from lfm_studio.engine.learned.mismatch import MismatchPool, check_jitter, resample_to_grid
from lfm_studio.engine.phantoms import beads, cells_in_ellipsoid
from lfm_studio.engine.simulation import ImagingSetup
from lfm_studio.engine.types import JSONValue

Split = Literal["train", "validation", "test"]
SPLIT_OFFSET: dict[str, int] = {"train": 0, "validation": 1_000_001, "test": 2_000_002}
SPLIT_SIZE = 1_000_001  # samples per split before seeds would overlap


@dataclass(frozen=True)
class TrainingDataSpec:
    """What the training phantoms and images look like.

    Attributes
    ----------
    phantoms : ``"beads"``, ``"cells"`` or ``"mix"`` (each sample picks one at random).
    objects : (min, max) number of beads or cells per volume (drawn uniformly; fewer when
        they do not fit).
    brightness : (min, max) relative peak brightness of an object (cells: per cell; beads:
        one value per volume).
    photons : expected photons in each image (one drawn per sample), e.g. ``(1e4, 1e5, 1e6)``.
    read_noise : camera read noise in photo-electrons (standard deviation per pixel).
    seed : base seed of the whole data set (see the module docstring for the split seeds).
    optics_jitter : optics-mismatch augmentation, relative (0.03 = +-3 %; 0 = off, at most 0.2):
        training images are formed through a pool of designs whose MLA focal length, Fourier
        lens focal length (where the kind has one), numerical aperture and wavelength are each
        scaled by a factor in ``[1 - j, 1 + j]`` (:func:`lfm_studio.engine.learned.mismatch.jittered_designs`,
        drawn once per training run from ``seed``); the model keeps the nominal projector.
        Needs the design (refused for a PSF stack without one).
    jitter_designs : number of jittered designs in that pool (each one PSF simulation).
    jitter_validation : also image the validation set through the jittered pool (default:
        validation stays on the nominal design, so early stopping and the checkpoint's
        validation scores measure the nominal instrument).
    """

    phantoms: Literal["beads", "cells", "mix"] = "mix"
    objects: tuple[int, int] = (4, 24)
    brightness: tuple[float, float] = (0.3, 1.0)
    photons: tuple[float, ...] = (1e4, 1e5, 1e6)
    read_noise: float = 1.0
    seed: int = 0
    optics_jitter: float = 0.0
    jitter_designs: int = 4
    jitter_validation: bool = False

    def __post_init__(self) -> None:
        if self.phantoms not in ("beads", "cells", "mix"):
            raise ValueError(f"phantoms must be 'beads', 'cells' or 'mix'; got {self.phantoms!r}.")
        low, high = self.objects
        if not 1 <= low <= high:
            raise ValueError(f"objects must be (min, max) with 1 <= min <= max; got {self.objects!r}.")
        if not (0 < self.brightness[0] <= self.brightness[1]):
            raise ValueError(f"brightness must be (min, max) with 0 < min <= max; got {self.brightness!r}.")
        if not self.photons or any(not (p > 0 and math.isfinite(p)) for p in self.photons):
            raise ValueError(f"photons must be positive photon counts per image; got {self.photons!r}.")
        if not self.read_noise >= 0:
            raise ValueError(f"read_noise must be >= 0 photo-electrons; got {self.read_noise!r}.")
        check_jitter(self.optics_jitter)
        if not (isinstance(self.jitter_designs, int) and self.jitter_designs >= 1):
            raise ValueError(f"jitter_designs must be an integer >= 1; got {self.jitter_designs!r}.")

    def to_dict(self) -> dict[str, JSONValue]:
        """JSON-ready form (stored in checkpoints)."""
        return {
            **asdict(self),
            "objects": list(self.objects),
            "brightness": list(self.brightness),
            "photons": list(self.photons),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, JSONValue]) -> TrainingDataSpec:
        """Inverse of :meth:`to_dict` (the values are checked by the constructor)."""
        # JSON values: mypy cannot see they fit the fields; __post_init__ checks them.
        fields = {**data, "objects": tuple(data["objects"]), "brightness": tuple(data["brightness"]),  # type: ignore[arg-type]
                  "photons": tuple(data["photons"])}  # type: ignore[arg-type]  # fmt: skip
        return cls(**fields)  # type: ignore[arg-type]


@dataclass(frozen=True)
class Sample:
    """One training pair: ``image (Py, Px)`` in photons and ``truth (Z, Vy, Vx)`` in photons per voxel."""

    image: torch.Tensor
    truth: torch.Tensor
    photons: float
    phantom: str
    seed: int


def sample_seed(spec: TrainingDataSpec, split: Split, index: int) -> int:
    """The seed of sample ``index`` of ``split`` (disjoint between splits, see the module docstring)."""
    if split not in SPLIT_OFFSET:
        raise ValueError(f"split must be one of {list(SPLIT_OFFSET)}; got {split!r}.")
    if not 0 <= index < SPLIT_SIZE:
        raise ValueError(f"index must be in [0, {SPLIT_SIZE}); got {index!r}.")
    return spec.seed * 3 * SPLIT_SIZE + SPLIT_OFFSET[split] + index


def make_sample(
    spec: TrainingDataSpec,
    setup: ImagingSetup,
    split: Split,
    index: int,
    *,
    imaging: ImagingSetup | MismatchPool | None = None,
) -> Sample:
    """Sample ``index`` of ``split`` on ``setup``'s volume grid (an :class:`~lfm_studio.engine.simulation.ImagingSetup`).

    The image is formed through ``setup``, or through ``imaging`` when given: another setup, or
    a :class:`~lfm_studio.engine.learned.mismatch.MismatchPool` that picks one of its jittered
    designs' setups by the sample's seed (optics-mismatch augmentation,
    :func:`lfm_studio.engine.learned.mismatch.jittered_designs`). The phantom is resampled
    onto the imaging grid when its voxels differ (another magnification); the truth stays on
    ``setup``'s grid. Deterministic: the same spec, setups, split and index give the same sample.

    Devices: the phantom is imaged on the projector's device, the noise drawn on the CPU (a seeded
    CPU :class:`torch.Generator`), and the sample's ``image`` and ``truth`` are CPU tensors whatever
    the projector's device; move them to it where they meet the projector again
    (:func:`lfm_studio.engine.optimize.end_to_end.sample_loss` does).
    """
    seed = sample_seed(spec, split, index)
    generator = torch.Generator().manual_seed(seed)
    kind = spec.phantoms
    if kind == "mix":
        kind = "beads" if torch.rand((), generator=generator) < 0.5 else "cells"
    count = int(torch.randint(spec.objects[0], spec.objects[1] + 1, (), generator=generator))
    low, high = spec.brightness
    (nz, ny, nx), (dz, dy, dx) = setup.volume_shape, setup.voxel_size
    shape, voxel = (int(nz), int(ny), int(nx)), (float(dz), float(dy), float(dx))
    if kind == "beads":
        level = low + (high - low) * float(torch.rand((), generator=generator))
        volume = beads(shape, count=count, voxel_size=voxel, seed=seed, allow_fewer=True).data * level
    else:
        semi = (0.45 * nz * dz, 0.45 * ny * dy, 0.45 * nx * dx)
        cell = min(3e-6, 0.25 * min(semi))
        volume = cells_in_ellipsoid(
            shape, voxel_size=voxel, seed=seed, semi_axes=semi, count=count,
            cell_semi_axes=(cell, cell, cell), brightness=(low, high),
        ).data  # fmt: skip
    volume = volume.to(dtype=torch.float32)
    through = (
        setup if imaging is None else imaging.pick(seed) if isinstance(imaging, MismatchPool) else imaging
    )
    projector = through.projector
    imaged = resample_to_grid(volume, voxel, tuple(through.volume_shape), tuple(through.voxel_size))
    with torch.no_grad():
        expected = projector.forward(imaged.to(device=projector.device, dtype=projector.dtype))
        # The noise is drawn on the CPU with the sample's CPU generator, whatever the projector's
        # device (a CPU generator cannot draw on a CUDA tensor): the same draws everywhere, and
        # on the CPU the numbers are those of the plain CPU path.
        expected = expected.clamp_min(0.0).float().cpu()
    photons = float(spec.photons[int(torch.randint(len(spec.photons), (), generator=generator))])
    total = float(expected.double().sum())
    scale = photons / total if total > 0 else 0.0
    image = torch.poisson(expected * scale, generator=generator)
    if spec.read_noise > 0:
        image = image + spec.read_noise * torch.randn(image.shape, generator=generator)
    return Sample(image, volume * scale, photons, kind, seed)


def make_samples(
    spec: TrainingDataSpec,
    setup: ImagingSetup,
    split: Split,
    count: int,
    start: int = 0,
    *,
    imaging: ImagingSetup | MismatchPool | None = None,
) -> list[Sample]:
    """Samples ``start .. start + count - 1`` of ``split`` (``imaging``: see :func:`make_sample`)."""
    return [make_sample(spec, setup, split, start + i, imaging=imaging) for i in range(count)]
