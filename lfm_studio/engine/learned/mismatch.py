"""Optics-mismatch augmentation: train on images of a slightly wrong instrument.

A real microscope never matches its design exactly. With ``TrainingDataSpec.optics_jitter``
``j`` > 0 (relative, e.g. 0.03 = +-3 %), :func:`jittered_designs` draws a small pool of
designs (``TrainingDataSpec.jitter_designs``, default 4) around the nominal one, each with its
own factors drawn uniformly from ``[1 - j, 1 + j]`` for

- the MLA focal length (one factor for the whole array: every lenslet's focal length scales),
- the Fourier (relay) lens focal length, where the kind has one,
- the objective's numerical aperture (kept below the immersion index),
- the emission wavelength.

Each jittered design's PSF stack is simulated with the system's own PSF code
(:func:`~lfm_studio.engine.simulation.simulate_psf`) and built into a projector
(:func:`~lfm_studio.engine.simulation.imaging_setup`): :func:`mismatch_pool`. Every training
sample is then imaged through one of them (:func:`~lfm_studio.engine.learned.data.make_sample`
with ``imaging=pool``), picked by the sample's seed, while the model keeps the nominal
projector. The phantom lives on the nominal volume grid (the truth); a jittered design with
another magnification has another voxel size, so the phantom is resampled onto the jittered
grid at the same physical positions (:func:`resample_to_grid`) before it is imaged.

Fields are set with the optimiser's design-space code (:class:`~lfm_studio.engine.design.space.DesignSpace`:
dotted paths, the new design validated once by its own checks): :func:`jitter_space`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from lfm_studio.engine.design.design import Design
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.design.space import DesignSpace, Parameter
from lfm_studio.engine.simulation import ImagingSetup

JITTER_LIMIT = 0.2
"""Largest accepted ``optics_jitter`` (20 %): beyond it the "instrument" is another design."""

POOL_SEED_OFFSET = 7_000_007
"""The pool of a data spec with seed ``S`` is drawn from seed ``S + POOL_SEED_OFFSET``."""

PICK_SEED_OFFSET = 11_000_011
"""Sample seed ``s`` picks its jittered design with a generator seeded ``s + PICK_SEED_OFFSET``
(its own stream, so the phantom and noise are those of the nominal sample with that seed)."""


def check_jitter(value: float, name: str = "optics_jitter") -> float:
    """``value`` if it is a finite fraction in ``[0, JITTER_LIMIT]``, else a ValueError naming ``name``."""
    if not (isinstance(value, int | float) and math.isfinite(value) and 0.0 <= value <= JITTER_LIMIT):
        raise ValueError(
            f"{name} must be a relative jitter between 0 and {JITTER_LIMIT:g} (e.g. 0.03 for +-3 %); "
            f"got {value!r}. Fix: give a fraction, not a percentage, at most {JITTER_LIMIT:g}."
        )
    return float(value)


def jitter_paths(design: Design) -> dict[str, list[str]]:
    """The design fields each jittered quantity scales: ``{quantity: [dotted paths]}``.

    Quantities: ``"mla focal length"`` (``mla.focal_length_mm``, or every lenslet's
    ``mla.lenslets[i].focal_length_mm``), ``"fourier lens focal length"`` (``relay.focal_length_mm``;
    only where the design has a relay), ``"numerical aperture"`` and ``"wavelength"``. Paths
    are those of the optimiser's design spaces (:mod:`lfm_studio.engine.design.space`).
    """
    mla = design.mla
    if hasattr(mla, "focal_length_mm"):
        lenslets = ["mla.focal_length_mm"]
    else:
        lenslets = [f"mla.lenslets[{i}].focal_length_mm" for i in range(len(mla.lenslets))]
    paths = {"mla focal length": lenslets}
    if getattr(design, "relay", None) is not None:
        paths["fourier lens focal length"] = ["relay.focal_length_mm"]
    paths["numerical aperture"] = ["objective.numerical_aperture"]
    paths["wavelength"] = ["wavelength_nm"]
    return paths


def jitter_space(design: Design, fraction: float) -> DesignSpace:
    """The design space of the jitter: every field of :func:`jitter_paths`, from ``(1 - f)`` to
    ``(1 + f)`` times its value in ``design`` (:meth:`DesignSpace.values_of` reads them back)."""
    nominal = DesignSpace(
        tuple(Parameter(p, low=0.0, high=0.0) for ps in jitter_paths(design).values() for p in ps)
    )
    values = nominal.values_of(design)
    return DesignSpace(
        tuple(
            Parameter(p, low=float(v) * (1 - fraction), high=float(v) * (1 + fraction))
            for p, v in values.items()
        )
    )


def jittered_design(design: Design, factors: dict[str, float]) -> Design:
    """``design`` with each quantity of :func:`jitter_paths` multiplied by ``factors[quantity]``
    (missing: 1), written with :meth:`DesignSpace.apply` (validated once by the design's checks).

    The numerical aperture is capped at 0.99 times the immersion index (a factor that would
    exceed it gives at most that, or the nominal NA when that is already higher).
    """
    space = jitter_space(design, 0.0)
    nominal = space.values_of(design)
    point: dict[str, float] = {}
    for quantity, paths in jitter_paths(design).items():
        for path in paths:
            value = float(nominal[path]) * factors.get(quantity, 1.0)
            if quantity == "numerical aperture":
                value = min(value, max(float(nominal[path]), 0.99 * design.objective.immersion_index))
            point[path] = value
    return space.apply(design, point)


def jittered_designs(design: Design, fraction: float, count: int = 4, seed: int = 0) -> list[Design]:
    """``count`` designs around ``design``, each quantity scaled by a factor in ``[1 - f, 1 + f]``.

    Deterministic for ``(design, fraction, count, seed)``; ``fraction`` 0 gives copies of
    ``design``. The factors are independent per design and quantity (uniform). Design
    warnings of the jittered designs (those of the nominal design, which the caller has seen,
    a few % off) are not repeated.
    """
    fraction = check_jitter(fraction)
    if not (isinstance(count, int) and count >= 1):
        raise ValueError(f"count must be an integer >= 1 (jittered designs in the pool); got {count!r}.")
    generator = torch.Generator().manual_seed(seed)
    quantities = list(jitter_paths(design))
    out = []
    for _ in range(count):
        draws = 2.0 * torch.rand(len(quantities), generator=generator, dtype=torch.float64) - 1.0
        factors = {q: 1.0 + fraction * float(d) for q, d in zip(quantities, draws, strict=True)}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DesignWarning)
            out.append(jittered_design(design, factors))
    return out


@dataclass(frozen=True)
class MismatchPool:
    """Jittered designs and the imaging setups of their simulated PSF stacks.

    :meth:`pick` chooses the setup a sample with a given seed is imaged through.
    """

    fraction: float
    designs: tuple[Design, ...]
    setups: tuple[ImagingSetup, ...]

    def pick(self, seed: int) -> ImagingSetup:
        """The setup of sample seed ``seed`` (deterministic, uniform over the pool)."""
        generator = torch.Generator().manual_seed(seed + PICK_SEED_OFFSET)
        return self.setups[int(torch.randint(len(self.setups), (), generator=generator))]


def mismatch_pool(
    design: Design,
    fraction: float,
    *,
    count: int = 4,
    seed: int = 0,
    simulate: Callable[[Design], ImagingSetup] | None = None,
) -> MismatchPool:
    """:func:`jittered_designs` with each design's PSF stack simulated and built into a setup.

    ``simulate`` maps a design to an :class:`~lfm_studio.engine.simulation.ImagingSetup`
    (default: ``imaging_setup(simulate_psf(design))``). Design warnings are not repeated (see
    :func:`jittered_designs`).
    """
    if simulate is None:
        from lfm_studio.engine.simulation import imaging_setup, simulate_psf

        def simulate(d: Design) -> ImagingSetup:
            return imaging_setup(simulate_psf(d))

    designs = jittered_designs(design, fraction, count, seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        setups = tuple(simulate(d) for d in designs)
    return MismatchPool(fraction, tuple(designs), setups)


def require_design_for_jitter(design: object, fraction: float) -> Design | None:
    """The design to jitter (None when ``fraction`` is 0); a ValueError naming the option when
    jitter is asked for without a design (training from a bare PSF stack, or its JSON dict)."""
    if fraction <= 0:
        return None
    if not isinstance(design, Design):
        raise ValueError(
            f"optics_jitter {fraction:g} (--optics-jitter) needs the design: the jittered PSFs are "
            "simulated from it, and this training started from a PSF stack without one. Fix: train "
            "from the design (drop --psf, or give a PSF file that records its design), or set "
            "optics_jitter to 0."
        )
    return design


def resample_to_grid(
    volume: torch.Tensor,
    voxel: Sequence[float],
    shape: Sequence[int],
    target_voxel: Sequence[float],
) -> torch.Tensor:
    """``volume`` (photons per voxel on a grid of ``voxel`` (dz, dy, dx) m) on a grid of ``shape``
    and ``target_voxel``, both centred on the optical axis: the density is sampled bilinearly (in y
    and x, zero outside) at the target voxel centres and multiplied by the ratio of voxel areas, so
    the photons are conserved (to the interpolation error). Depths must match. The same grid
    returns ``volume`` itself."""
    if tuple(shape) == tuple(volume.shape) and all(
        math.isclose(a, b, rel_tol=1e-9) for a, b in zip(voxel, target_voxel, strict=True)
    ):
        return volume
    if shape[0] != volume.shape[0]:
        raise ValueError(
            f"the jittered projector has {shape[0]} depths and the nominal volume {volume.shape[0]}; "
            "optics jitter keeps the depths, so they must match."
        )

    def scale(axis: int) -> float:  # normalised target coordinate -> normalised source coordinate
        half_target, half_source = (shape[axis] - 1) / 2, (volume.shape[axis] - 1) / 2
        if half_source == 0:
            return 0.0
        return (half_target * target_voxel[axis]) / (half_source * voxel[axis]) if half_target > 0 else 0.0

    theta = torch.tensor([[scale(2), 0.0, 0.0], [0.0, scale(1), 0.0]], dtype=volume.dtype)
    grid = torch.nn.functional.affine_grid(
        theta.expand(volume.shape[0], 2, 3), [volume.shape[0], 1, shape[1], shape[2]], align_corners=True
    )
    out = torch.nn.functional.grid_sample(
        volume[:, None], grid, mode="bilinear", padding_mode="zeros", align_corners=True
    )
    area_ratio = (target_voxel[1] * target_voxel[2]) / (voxel[1] * voxel[2])
    return out[:, 0] * area_ratio
