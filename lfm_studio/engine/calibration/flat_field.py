"""Flat-field (vignetting) correction from a radiometry frame.

Each lenslet of a radiometry frame collects the light of the same patch of a uniform
slide, so differences in the light per lenslet are vignetting (and dust). The smooth
*envelope* ``v(y, x)`` is a least-squares 2D polynomial of degree ``DEGREE`` in the
normalised frame coordinates, fitted to the light per lenslet at the lenslet centres
(lenslets flagged by the lattice fit are left out) and scaled to 1 at its median. A
frame is corrected by dividing it by ``v``; dividing by the smooth envelope, not by the
radiometry frame itself, leaves the dark gaps between lenslet disks finite.
"""

from __future__ import annotations

import torch

DEGREE = 4


def _basis(points: torch.Tensor, shape: tuple[int, int], degree: int) -> torch.Tensor:
    """Monomials ``u^a w^b`` (a + b <= degree) of normalised coordinates in [-1, 1]; (N, terms)."""
    ny, nx = shape
    u = 2.0 * points[:, 0].to(torch.float64) / max(ny - 1, 1) - 1.0
    w = 2.0 * points[:, 1].to(torch.float64) / max(nx - 1, 1) - 1.0
    return torch.stack([u**a * w**b for a in range(degree + 1) for b in range(degree + 1 - a)], dim=1)


def fit_envelope(
    centres: torch.Tensor, light: torch.Tensor, shape: tuple[int, int], *, degree: int = DEGREE
) -> torch.Tensor:
    """Polynomial coefficients of the envelope through ``light`` (L,) at ``centres`` (L, 2) (y, x) px.

    Normalised so that the envelope's median over the given centres is 1.
    """
    basis = _basis(centres, shape, degree)
    if basis.shape[0] < basis.shape[1]:
        raise ValueError(
            f"the flat field needs at least {basis.shape[1]} usable lenslets for a degree-{degree} envelope; "
            f"got {basis.shape[0]}. Fix: use a larger radiometry frame."
        )
    coefficients = torch.linalg.lstsq(basis, light.to(torch.float64)[:, None]).solution[:, 0]
    scale = float((basis @ coefficients).median())
    return coefficients / scale


def envelope_at(coefficients: torch.Tensor, points: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """Envelope values at ``points`` (N, 2) (y, x) px of a frame of ``shape``."""
    degree = _degree_of(coefficients.numel())
    return _basis(points, shape, degree) @ coefficients.to(torch.float64)


def envelope_map(coefficients: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """The envelope over the whole frame, (Y, X) float64 (evaluated separably: ``U C W^T``)."""
    ny, nx = shape
    degree = _degree_of(coefficients.numel())
    u = 2.0 * torch.arange(ny, dtype=torch.float64) / max(ny - 1, 1) - 1.0
    w = 2.0 * torch.arange(nx, dtype=torch.float64) / max(nx - 1, 1) - 1.0
    powers = torch.arange(degree + 1, dtype=torch.float64)
    table = torch.zeros(degree + 1, degree + 1, dtype=torch.float64)
    terms = [(a, b) for a in range(degree + 1) for b in range(degree + 1 - a)]
    for (a, b), c in zip(terms, coefficients.to(torch.float64).tolist(), strict=True):
        table[a, b] = c
    return (u[:, None] ** powers) @ table @ (w[:, None] ** powers).T


def flat_field_map(coefficients: torch.Tensor, shape: tuple[int, int]) -> torch.Tensor:
    """The envelope a frame of ``shape`` is divided by: values below 5 % of its median clamped there."""
    return envelope_map(coefficients, shape).clamp_min(0.05)


def flat_field(frame: torch.Tensor, coefficients: torch.Tensor) -> torch.Tensor:
    """``frame`` divided by :func:`flat_field_map`."""
    return frame.to(torch.float64) / flat_field_map(coefficients, (frame.shape[-2], frame.shape[-1]))


def _degree_of(terms: int) -> int:
    degree = 0
    while (degree + 1) * (degree + 2) // 2 < terms:
        degree += 1
    if (degree + 1) * (degree + 2) // 2 != terms:
        raise ValueError(f"{terms} envelope coefficients do not make a full 2D polynomial.")
    return degree
