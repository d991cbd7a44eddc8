"""Thesis Algorithm 1, MLA concatenation: the MLA mask of a cell layout from precomputed lens patches.

The thesis (section 3.1.2.4) precomputes, for every focal length ``f`` of the list, a
thin-lens patch ``D[f] = circ * exp(-j k (x^2 + y^2) / (2 f))`` (eq. 3.15) of the
largest aperture; each lenslet ``(x_i, y_i), p_i, f_i`` (pixels) then gets the centre
``p_i x p_i`` crop of ``D[f_i]`` pasted at ``PM[x_i - p_i/2 : x_i + p_i/2, ...]`` of a
``K x K`` array of zeros.

Choices where the pseudo-code is ambiguous
------------------------------------------
- Sampling: the plane's ``M`` cells are ``pixels_per_cell`` pixels each (``K = M c``),
  so every lenslet edge falls between pixels and a lenslet of ``s`` cells is exactly
  ``p = s c`` pixels. Pixel ``n`` is centred at ``(n + 1/2 - K/2)`` pixels from the axis,
  which is the engine :class:`~lfm_studio.engine.optics.grid.Grid` convention
  ``(n - K // 2)`` when ``K`` is odd (:func:`mask_coordinates`).
- Crop parity: a centred crop of ``p`` pixels from a patch of ``P`` pixels needs
  ``P - p`` even (otherwise its centre is half a pixel off the lens axis), so the
  dictionary holds one patch per (focal length, parity of the size in pixels).
- Aperture: a crop of the largest circular patch is a square of phase; the thesis
  leaves open whether a smaller lenslet keeps that square or gets its own circle. We
  apply the lenslet's own aperture after the crop: ``"square"`` keeps the whole crop,
  ``"circle"`` zeroes the pixels whose centre lies beyond ``p/2`` pixels (rim inclusive,
  like the engine's binary disk).
- Rows are ``y`` and columns ``x`` (the engine's ``(ny, nx)`` layout); the thesis writes
  ``PM[x, y]``.
- ``k = 2 pi n / lambda`` in the medium of index ``n`` behind the array.

The optimiser scores a candidate through its :class:`Design`, whose MLA the engine turns
into a transmission with :func:`~lfm_studio.engine.optics.mla.mla_transmission` (Algorithm 1
generalised to any centre); ``tests/engine/optimize/test_algorithm2.py`` checks that both
give the same mask on a cell layout. This module is the literal algorithm, e.g. to export
a candidate's mask for fabrication.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from lfm_studio.engine.optimize.mla_cells import Block, MLAPlane


def _check(pixels_per_cell: int, wavelength_nm: float, refractive_index: float) -> None:
    if isinstance(pixels_per_cell, bool) or not isinstance(pixels_per_cell, int) or pixels_per_cell < 1:
        raise ValueError(f"pixels_per_cell must be an integer >= 1; got {pixels_per_cell!r}. Fix: e.g. 16.")
    if not (math.isfinite(wavelength_nm) and wavelength_nm > 0.0):
        raise ValueError(f"wavelength_nm must be a number > 0 nm; got {wavelength_nm!r}. Fix: e.g. 525.")
    if not (math.isfinite(refractive_index) and refractive_index > 0.0):
        raise ValueError(f"refractive_index must be > 0; got {refractive_index!r}. Fix: 1.0 for air.")


def mask_coordinates(plane: MLAPlane, pixels_per_cell: int) -> torch.Tensor:
    """Pixel-centre coordinates along x (and y) of the mask, metres from the axis, float64 ``(K,)``."""
    size = plane.cells * pixels_per_cell
    pixel = plane.cell_um * 1e-6 / pixels_per_cell
    return (torch.arange(size, dtype=torch.float64) + 0.5 - size / 2.0) * pixel


def _lens_patch(size: int, pixel: float, k: float, focal_length: float) -> torch.Tensor:
    """Thin-lens transmission on a ``size x size`` patch centred on the lens axis (complex128)."""
    offsets = (torch.arange(size, dtype=torch.float64) - (size - 1) / 2.0) * pixel
    r2 = offsets[None, :] ** 2 + offsets[:, None] ** 2
    phase = (-0.5 * k / focal_length) * r2
    return torch.polar(torch.ones_like(phase), phase)


def _crop(patch: torch.Tensor, size: int) -> torch.Tensor:
    start = (patch.shape[-1] - size) // 2
    return patch[start : start + size, start : start + size]


def concatenate(
    plane: MLAPlane,
    blocks: Sequence[Block],
    *,
    pixels_per_cell: int,
    wavelength_nm: float,
    refractive_index: float = 1.0,
) -> torch.Tensor:
    """Algorithm 1: the complex MLA transmission ``(K, K)`` of the lenslets ``blocks``, complex128.

    Parameters
    ----------
    plane : MLAPlane
        The cell grid (cell size, focal-length rule, aperture shape).
    blocks : sequence of Block
        Non-overlapping lenslets (e.g. an Algorithm 2 result).
    pixels_per_cell : int
        Samples per cell side; ``K = plane.cells * pixels_per_cell``.
    wavelength_nm : float
        Vacuum wavelength, nanometres.
    refractive_index : float
        Index behind the array.

    Returns
    -------
    Tensor ``(K, K)`` (rows y, columns x), zero outside the lenslets; pixel centres at
    :func:`mask_coordinates`.
    """
    _check(pixels_per_cell, wavelength_nm, refractive_index)
    c = pixels_per_cell
    pixel = plane.cell_um * 1e-6 / c
    k = 2.0 * math.pi * refractive_index / (wavelength_nm * 1e-9)
    for block in blocks:
        reason = plane.outside_reason(block)
        if reason:
            raise ValueError(
                f"blocks must be lenslets of the plane; {reason}. Fix: use plane.initial_blocks() or merges."
            )
    # Lines 4-6: one patch per focal length (and per parity, see the module docstring), largest size.
    largest: dict[tuple[float, int], int] = {}
    for block in blocks:
        key = (plane.focal_length_mm(block), (block.size * c) % 2)
        largest[key] = max(largest.get(key, 0), block.size * c)
    library = {key: _lens_patch(size, pixel, k, key[0] * 1e-3) for key, size in largest.items()}
    size = plane.cells * c
    mask = torch.zeros((size, size), dtype=torch.complex128)
    # Lines 7-11: crop and paste each lenslet.
    for block in blocks:
        p = block.size * c
        patch = _crop(library[(plane.focal_length_mm(block), p % 2)], p)
        if plane.shape == "circle":
            offsets = torch.arange(p, dtype=torch.float64) - (p - 1) / 2.0
            inside = offsets[None, :] ** 2 + offsets[:, None] ** 2 <= (p / 2.0) ** 2
            patch = patch * inside
        row, col = block.j * c, block.i * c
        mask[row : row + p, col : col + p] = patch
    return mask
