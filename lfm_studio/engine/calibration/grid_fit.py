"""Refined lenslet lattice: centroids of every lenslet, a robust least-squares lattice fit.

Starting from the coarse Fourier lattice, the centroid of each lenslet's disk is
measured (:mod:`~lfm_studio.engine.calibration.centroids`); the six affine lattice
parameters (origin and two vectors) are the least-squares fit of
``centre(i, j) = origin + i row + j col`` to them. The fit is done first on the central
lenslets (where a small pitch error has not yet accumulated), then on all, each time
re-measuring from the updated prediction and leaving flagged lenslets out:

- ``EDGE``: the lenslet's disk (plus 1 px) leaves the frame;
- ``DIM``: the lenslet's light is below ``DIM_FRACTION`` of the median of its neighbours
  (dust, a dead region), or below ``DARK_FRACTION`` of the bright lenslets' light (the
  95th percentile over the frame): outside the field of view, where a lenslet amid dark
  neighbours is not dim next to them but its centroid is noise;
- ``RESIDUAL``: its centroid is more than ``max(RESIDUAL_MADS robust sigmas, RESIDUAL_FLOOR)``
  from the fit (dust on one side, hot or dead pixels inside the disk).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lfm_studio.engine.calibration.centroids import measure_centroids
from lfm_studio.engine.calibration.lattice import LensletLattice

EDGE, DIM, RESIDUAL = 1, 2, 4
FLAG_NAMES = {EDGE: "edge", DIM: "dim", RESIDUAL: "residual"}
DIM_FRACTION = 0.7
DARK_FRACTION = 0.1  # of the 95th percentile of lenslet light: a dark lenslet, outside the field
RESIDUAL_MADS = 6.0
RESIDUAL_FLOOR = 0.25  # px: below this a centroid is never called an outlier
CENTRAL_LENSLETS = 12  # first pass: lenslets within this many of the origin


@dataclass(frozen=True)
class LatticeFit:
    """The refined lattice and the per-lenslet measurements behind it.

    Attributes
    ----------
    lattice : fitted lattice.
    indices : (L, 2) int64 lenslet indices (i, j).
    measured : (L, 2) float64 measured centroids (y, x) px.
    residual : (L,) float64 distance measured - fitted, px.
    mass : (L,) float64 background-subtracted light per lenslet.
    flags : (L,) int64 bit set of ``EDGE | DIM | RESIDUAL`` (0: used in the fit).
    """

    lattice: LensletLattice
    indices: torch.Tensor
    measured: torch.Tensor
    residual: torch.Tensor
    mass: torch.Tensor
    flags: torch.Tensor

    @property
    def used(self) -> torch.Tensor:
        """(L,) bool, lenslets the fit used."""
        return self.flags == 0

    @property
    def rms_residual(self) -> float:
        """RMS residual of the used lenslets, px."""
        return float(self.residual[self.used].pow(2).mean().sqrt())


def fit_lattice(indices: torch.Tensor, centres: torch.Tensor) -> LensletLattice:
    """Least-squares affine lattice through ``centres`` (L, 2) (y, x) at ``indices`` (L, 2) (i, j)."""
    design = torch.cat((torch.ones(indices.shape[0], 1, dtype=torch.float64), indices.to(torch.float64)), 1)
    solution = torch.linalg.lstsq(design, centres.to(torch.float64)).solution  # (3, 2)
    return LensletLattice(
        origin=(float(solution[0, 0]), float(solution[0, 1])),
        row_vector=(float(solution[1, 0]), float(solution[1, 1])),
        col_vector=(float(solution[2, 0]), float(solution[2, 1])),
    )


def _dim(indices: torch.Tensor, mass: torch.Tensor) -> torch.Tensor:
    """Lenslets darker than ``DIM_FRACTION`` of the median of their 5 x 5 neighbourhood, or than
    ``DARK_FRACTION`` of the 95th percentile of all lenslets' light (outside the field of view)."""
    lo = indices.min(dim=0).values
    shape = (indices.max(dim=0).values - lo + 1).tolist()
    grid = torch.full(shape, float("nan"), dtype=torch.float64)
    local = indices - lo
    grid[local[:, 0], local[:, 1]] = mass
    padded = torch.nn.functional.pad(grid[None, None], (2, 2, 2, 2), value=float("nan"))[0, 0]
    patches = padded.unfold(0, 5, 1).unfold(1, 5, 1).reshape(shape[0], shape[1], 25)
    reference = patches.nanmedian(dim=-1).values[local[:, 0], local[:, 1]]
    dark = mass < DARK_FRACTION * torch.quantile(mass, 0.95)
    return (mass < DIM_FRACTION * reference) | dark


def disk_leaves_frame(centres: torch.Tensor, shape: torch.Size, reach: float) -> torch.Tensor:
    """(L,) bool: a disk of radius ``reach`` px around each centre leaves the frame."""
    ny, nx = shape
    y, x = centres[:, 0], centres[:, 1]
    return (y - reach < -0.5) | (y + reach > ny - 0.5) | (x - reach < -0.5) | (x + reach > nx - 0.5)


def refine_lattice(
    image: torch.Tensor, start: LensletLattice, *, disk_diameter: float, background: float = 0.0
) -> LatticeFit:
    """Refine ``start`` on ``image`` (Y, X, dark subtracted) from the centroids of every lenslet.

    Parameters
    ----------
    image : (Y, X) radiometry frame, dark subtracted, defects replaced.
    start : coarse lattice (e.g. from :func:`~lfm_studio.engine.calibration.grid_fourier.fourier_lattice`).
    disk_diameter : expected diameter of a lenslet's disk, px (sets the window radius).
    background : level of the unlit gaps, subtracted before weighting.
    """
    lattice = start
    radius = 0.5 * min(min(start.pitch), max(disk_diameter + 2.0, 3.0))
    reach = 0.5 * disk_diameter + 1.0
    indices = start.indices_inside((image.shape[-2], image.shape[-1]), margin=0.5)
    if indices.shape[0] < 4:
        raise ValueError(
            f"only {indices.shape[0]} whole lenslets fit on the {tuple(image.shape)} frame at pitch "
            f"{start.pitch[0]:.4g} x {start.pitch[1]:.4g} px; at least 4 are needed. "
            "Fix: use a larger frame or check the design's pitch and pixel size."
        )
    flags = torch.zeros(indices.shape[0], dtype=torch.int64)
    central = (indices.abs() <= CENTRAL_LENSLETS).all(dim=1)  # around lenslet (0, 0), the origin
    for subset in (central, torch.ones_like(central)):
        spots = measure_centroids(image, lattice.centres(indices), radius=radius, background=background)
        flags = torch.where(disk_leaves_frame(spots.centres, image.shape, reach), EDGE, 0)
        flags = flags | torch.where(_dim(indices, spots.mass), DIM, 0)
        keep = subset & (flags == 0)
        for _ in range(3):
            lattice = fit_lattice(indices[keep], spots.centres[keep])
            residual = torch.linalg.vector_norm(spots.centres - lattice.centres(indices), dim=1)
            sigma = 1.4826 * float((residual[keep] - residual[keep].median()).abs().median())
            limit = max(RESIDUAL_MADS * sigma + float(residual[keep].median()), RESIDUAL_FLOOR)
            outlier = residual > limit
            new_keep = subset & (flags == 0) & ~outlier
            if bool((new_keep == keep).all()):
                break
            keep = new_keep
        flags = flags | torch.where(outlier, RESIDUAL, 0)
    return LatticeFit(
        lattice=lattice,
        indices=indices,
        measured=spots.centres,
        residual=residual,
        mass=spots.mass,
        flags=flags,
    )
