"""Coarse lenslet lattice from the Fourier peaks of a radiometry frame.

The lenslet pattern is periodic, so its spectrum has peaks on the reciprocal lattice.
The two strongest, roughly perpendicular peaks in a band around the nominal lenslet
frequency give the reciprocal vectors ``k1, k2`` (cycles/px); their sub-bin position
comes from a Gaussian (log-parabola) fit over a Hann-windowed spectrum. The real-space
lattice vectors are the columns of ``inverse([k1; k2])``, and the offset follows from the
phase of the frame's exact DFT at ``k1`` and ``k2`` (a lenslet disk is symmetric, so its
transform is real and the phase is that of the lattice origin). The result is good to a
few hundredths of a pixel in pitch; :mod:`~lfm_studio.engine.calibration.grid_fit`
refines it with centroids.
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine import fft
from lfm_studio.engine.calibration.lattice import LensletLattice

#: A peak must stand this many times above the median power of its band to count as a grid.
MIN_PEAK_CONTRAST = 200.0
#: Band searched for the fundamental peaks, as factors of the nominal lenslet frequency.
BAND = (0.4, 2.5)


class NoGridError(ValueError):
    """The frame shows no periodic lenslet pattern."""


def _hann(n: int) -> torch.Tensor:
    return 0.5 - 0.5 * torch.cos(2.0 * math.pi * (torch.arange(n, dtype=torch.float64) + 0.5) / n)


def _signed(k: torch.Tensor, n: int) -> torch.Tensor:
    return torch.where(k > n // 2, k - n, k)


def _interpolate(power: torch.Tensor, ky: int, kx: int) -> tuple[float, float]:
    """Sub-bin peak position (signed ky, kx) by a log-parabola through the 3 neighbours per axis."""
    ny = power.shape[0]

    def at(y: int, x: int) -> float:
        if x < 0:  # Hermitian symmetry of the real input's spectrum
            y, x = -y, -x
        return max(float(power[y % ny, x]), 1e-300)

    def offset(m: float, c: float, p: float) -> float:
        lm, lc, lp = math.log(m), math.log(c), math.log(p)
        denominator = lm - 2.0 * lc + lp
        return 0.0 if denominator >= 0 else 0.5 * (lm - lp) / denominator

    dy = offset(at(ky - 1, kx), at(ky, kx), at(ky + 1, kx))
    dx = offset(at(ky, kx - 1), at(ky, kx), at(ky, kx + 1))
    return float(_signed(torch.tensor(ky), ny)) + dy, kx + dx


def _phase(image: torch.Tensor, k: torch.Tensor, centre: torch.Tensor) -> float:
    """Phase (rad) of the DFT of ``image`` at frequency ``k`` (y, x cycles/px), positions from ``centre``."""
    ny, nx = image.shape
    ey = torch.exp(-2j * math.pi * k[0] * (torch.arange(ny, dtype=torch.float64) - centre[0]))
    ex = torch.exp(-2j * math.pi * k[1] * (torch.arange(nx, dtype=torch.float64) - centre[1]))
    value = ey @ (image.to(torch.complex128) @ ex)
    return float(torch.angle(value))


def fourier_lattice(image: torch.Tensor, nominal_pitch: float) -> LensletLattice:
    """Estimate the lenslet lattice of a dark-subtracted radiometry ``image`` (Y, X).

    Parameters
    ----------
    image : (Y, X) real tensor, the radiometry frame (dark subtracted, defects replaced).
    nominal_pitch : expected lenslet pitch on the frame, px (from the design).

    Returns
    -------
    The lattice with its origin at the lenslet nearest the frame centre.

    Raises
    ------
    NoGridError
        When no peak stands :data:`MIN_PEAK_CONTRAST` times above its band.
    """
    ny, nx = image.shape
    data = image.to(torch.float64)
    window = _hann(ny)[:, None] * _hann(nx)[None, :]
    weighted = (data - data.mean()) * window
    power = fft.rfft2(weighted.to(torch.float32)).abs().to(torch.float64) ** 2
    fy = _signed(torch.arange(ny), ny).to(torch.float64)[:, None] / ny
    fx = torch.arange(power.shape[1], dtype=torch.float64)[None, :] / nx
    rho = torch.sqrt(fy**2 + fx**2)
    f0 = 1.0 / nominal_pitch
    band = (rho > BAND[0] * f0) & (rho < BAND[1] * f0)
    if not bool(band.any()):
        raise NoGridError(
            f"nominal_pitch {nominal_pitch:.4g} px leaves no frequencies to search on a {ny} x {nx} frame. "
            "Fix: check the design's lenslet pitch and pixel size."
        )
    masked = torch.where(band, power, torch.zeros_like(power))
    floor = float(power[band].median())
    first = int(torch.argmax(masked))
    k1y, k1x = divmod(first, power.shape[1])
    contrast = float(power[k1y, k1x]) / max(floor, 1e-300)
    if contrast < MIN_PEAK_CONTRAST:
        raise NoGridError(
            f"the radiometry frame shows no lenslet grid: the strongest periodic peak near the nominal "
            f"pitch {nominal_pitch:.4g} px stands only {contrast:.3g}x above the background "
            f"(a grid gives > {MIN_PEAK_CONTRAST:.0f}x). Fix: record the radiometry frame of a uniform "
            "fluorescent slide with the MLA in place and in focus, or check the design's pitch and pixel size."
        )
    direction = torch.tensor([fy[k1y, 0], fx[0, k1x]])
    cosine = (fy * direction[0] + fx * direction[1]) / (rho.clamp_min(1e-12) * direction.norm())
    second = int(torch.argmax(torch.where(cosine.abs() < 0.5, masked, torch.zeros_like(masked))))
    k2y, k2x = divmod(second, power.shape[1])
    peaks = [_interpolate(power, k1y, k1x), _interpolate(power, k2y, k2x)]
    k = torch.tensor([[py / ny, px / nx] for py, px in peaks], dtype=torch.float64)
    basis = torch.linalg.inv(k)  # columns: real-space lattice vectors (y, x)
    centre = torch.tensor([(ny - 1) / 2.0, (nx - 1) / 2.0], dtype=torch.float64)
    phases = torch.tensor([_phase(weighted, k[i], centre) for i in range(2)], dtype=torch.float64)
    origin = centre + basis @ (-phases / (2.0 * math.pi))
    a, b = basis[:, 0], basis[:, 1]
    col, row = (a, b) if abs(float(a[1])) >= abs(float(b[1])) else (b, a)
    col = col if float(col[1]) > 0 else -col
    row = row if float(row[0]) > 0 else -row
    lattice = LensletLattice(
        origin=(float(origin[0]), float(origin[1])),
        row_vector=(float(row[0]), float(row[1])),
        col_vector=(float(col[0]), float(col[1])),
    )
    return _bright_sites(data, lattice).recentred((float(centre[0]), float(centre[1])))


def _bright_sites(image: torch.Tensor, lattice: LensletLattice) -> LensletLattice:
    """Move the origin by half a cell when the cell corners are brighter than the sites.

    A disk larger than 1.22 pitches has a negative transform at the fundamental, which
    puts the phase-derived origin in the gaps; comparing the mean brightness at the
    sites and at the cell corners settles it.
    """
    indices = lattice.indices_inside((image.shape[-2], image.shape[-1]), margin=1.0)
    if indices.shape[0] == 0:
        return lattice
    sites = lattice.centres(indices)
    corners = sites + 0.5 * (torch.tensor(lattice.row_vector) + torch.tensor(lattice.col_vector))

    def mean_at(points: torch.Tensor) -> float:
        r = points[:, 0].round().long().clamp(0, image.shape[0] - 1)
        c = points[:, 1].round().long().clamp(0, image.shape[1] - 1)
        return float(image[r, c].mean())

    if mean_at(sites) >= mean_at(corners):
        return lattice
    shift = 0.5 * (torch.tensor(lattice.row_vector) + torch.tensor(lattice.col_vector))
    return LensletLattice(
        origin=(lattice.origin[0] + float(shift[0]), lattice.origin[1] + float(shift[1])),
        row_vector=lattice.row_vector,
        col_vector=lattice.col_vector,
    )
