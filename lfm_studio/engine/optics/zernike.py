"""Zernike polynomials in Noll's indexing, normalised to unit RMS over the unit disk.

Noll (J. Opt. Soc. Am. 66, 207, 1976): index ``j >= 1`` names the radial order ``n`` and
azimuthal frequency ``m >= 0``; within an order ``m`` rises with ``j``, and for ``m > 0``
an even ``j`` is the cosine term, an odd ``j`` the sine term::

    j  1  2  3  4  5  6  7  8  9  10  11
    n  0  1  1  2  2  2  3  3  3   3   4
    m  0  1  1  0  2  2  1  1  3   3   0
       piston, tilt x (2 rho cos), tilt y (2 rho sin), defocus sqrt(3) (2 rho^2 - 1), ...,
       primary spherical sqrt(5) (6 rho^4 - 6 rho^2 + 1)

``Z_j = sqrt(n + 1) R_n^0(rho)`` (``m = 0``) or ``sqrt(2 (n + 1)) R_n^m(rho) cos / sin(m theta)``,
so ``(1 / pi) integral_disk Z_i Z_j = delta_ij`` (unit RMS, orthonormal; tested).

:func:`zernike` evaluates one polynomial at Cartesian points ``(x, y)`` in units of the
disk radius, as a polynomial in ``x`` and ``y`` (``rho^m cos(m theta)`` is the real part
of ``(x + j y)^m``): no ``atan2``, smooth at the centre, and every input may be a tensor
that keeps its graph. :func:`zernike_phase` sums ``2 pi c_j Z_j`` for coefficients in
waves: the one function every pupil-phase user calls (one code path);
:func:`radial_zernike_phase` is its form on the normalised pupil radius alone, for the
rotationally symmetric (``m = 0``) terms that a radial integral such as the Debye
integral can carry (:func:`check_rotationally_symmetric` refuses the others by name).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import torch

Scalar = float | torch.Tensor


def noll_to_nm(j: int) -> tuple[int, int]:
    """Radial order ``n`` and azimuthal frequency ``m >= 0`` of Noll index ``j >= 1``."""
    if isinstance(j, bool) or not isinstance(j, int) or j < 1:
        raise ValueError(f"Noll index must be an integer >= 1; got {j!r}. Fix: e.g. 4 for defocus.")
    n = 0
    while (n + 1) * (n + 2) // 2 < j:
        n += 1
    first = n * (n + 1) // 2 + 1  # Noll index of the first term of order n
    k = j - first  # 0 .. n
    # m takes the values of parity n, each m > 0 twice: n even 0, 2, 2, 4, 4, ...; n odd 1, 1, 3, 3, ...
    m = 2 * ((k + 1) // 2) if n % 2 == 0 else 2 * (k // 2) + 1
    return n, m


def is_rotationally_symmetric(j: int) -> bool:
    """Whether Noll term ``j`` has ``m = 0`` (piston, defocus, spherical, ...)."""
    return noll_to_nm(j)[1] == 0


def _radial_coefficients(n: int, m: int) -> list[tuple[float, int]]:
    """``R_n^m(rho) = sum_k c_k rho^(n - 2k)`` as ``(c_k, (n - m) / 2 - k)``: powers of ``rho^2`` beyond ``rho^m``."""
    out = []
    for k in range((n - m) // 2 + 1):
        c = (
            (-1) ** k
            * math.factorial(n - k)
            / (math.factorial(k) * math.factorial((n + m) // 2 - k) * math.factorial((n - m) // 2 - k))
        )
        out.append((float(c), (n - m) // 2 - k))
    return out


def zernike(j: int, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Noll Zernike ``Z_j`` at ``(x, y)`` in units of the disk radius (broadcast), unit RMS on the disk.

    Outside the unit disk the polynomial continues (callers weight by their own pupil).
    """
    n, m = noll_to_nm(j)
    x, y = torch.broadcast_tensors(x, y)
    rho2 = x * x + y * y
    radial = torch.zeros_like(rho2)
    for c, power in _radial_coefficients(n, m):
        radial = radial + c * rho2**power
    if m == 0:
        return math.sqrt(n + 1) * radial
    re, im = torch.ones_like(x), torch.zeros_like(x)  # (x + j y)^m, real and imaginary parts
    for _ in range(m):
        re, im = re * x - im * y, re * y + im * x
    angular = re if j % 2 == 0 else im
    return math.sqrt(2.0 * (n + 1)) * radial * angular


def check_zernike_terms(terms: Iterable[int], where: str = "zernike_waves") -> None:
    """Raise ``ValueError`` naming ``where`` for an index that is not a Noll index."""
    for j in terms:
        if isinstance(j, bool) or not isinstance(j, int) or j < 1:
            raise ValueError(
                f"{where}: Noll indices must be integers >= 1; got {j!r}. Fix: e.g. 4 for defocus."
            )


def zernike_phase(
    waves: Mapping[int, Scalar], x: torch.Tensor, y: torch.Tensor, radius: Scalar
) -> torch.Tensor:
    """Phase in radians ``2 pi sum_j c_j Z_j(x / radius, y / radius)`` (``c_j`` in waves).

    ``x``, ``y`` and ``radius`` in the same length unit; any of them and the coefficients may
    be tensors (float64 is used; the graph is kept). Zero for no terms.
    """
    check_zernike_terms(waves)
    u, v = x / radius, y / radius
    u, v = torch.broadcast_tensors(u, v)
    phase = torch.zeros_like(u, dtype=torch.float64)
    for j in sorted(waves):
        c = waves[j]
        c = c.to(dtype=torch.float64, device=phase.device) if isinstance(c, torch.Tensor) else float(c)
        phase = phase + c * zernike(j, u.to(torch.float64), v.to(torch.float64))
    return 2.0 * math.pi * phase


def check_rotationally_symmetric(terms: Iterable[int], where: str = "zernike_waves") -> None:
    """Raise ``ValueError`` naming the first term of ``terms`` with ``m != 0`` (and the Noll indices
    that are allowed): a radial (rotationally symmetric) integral cannot carry it."""
    check_zernike_terms(terms, where)
    for j in terms:
        n, m = noll_to_nm(j)
        if m != 0:
            raise ValueError(
                f"{where}: Noll {j} (radial order n = {n}, azimuthal frequency m = {m}) is not rotationally "
                "symmetric; the radial Debye integral of a conventional LFM's native-image-plane field "
                "assumes a rotationally symmetric pupil, so only m = 0 terms can enter it (Noll 1 piston, "
                "4 defocus, 11 primary spherical, 22 secondary spherical, 37, ...). Fix: remove the term, "
                "or use kind 'fourier'."
            )


def radial_zernike_phase(waves: Mapping[int, Scalar], rho: torch.Tensor) -> torch.Tensor:
    """Phase in radians ``2 pi sum_j c_j Z_j(rho)`` of rotationally symmetric terms at normalised
    pupil radii ``rho`` (``rho = 1`` the pupil rim); a term with ``m != 0`` raises ``ValueError``
    (:func:`check_rotationally_symmetric`). Same polynomials and graph as :func:`zernike_phase`."""
    check_rotationally_symmetric(waves)
    return zernike_phase(waves, rho, torch.zeros_like(rho), 1.0)


def max_abs_phase(waves: Mapping[int, Scalar]) -> float:
    """Upper bound (rad) of ``|2 pi sum_j c_j Z_j|`` on the unit disk: ``2 pi sum |c_j| max|Z_j|``,
    ``max|Z_j| = sqrt(n + 1)`` (``m = 0``) or ``sqrt(2 (n + 1))`` (``|R_n^m| <= 1``). Floats of the values."""
    bound = 0.0
    for j, c in waves.items():
        n, m = noll_to_nm(j)
        value = float(c.detach()) if isinstance(c, torch.Tensor) else float(c)
        bound += abs(value) * math.sqrt((n + 1) * (1 if m == 0 else 2))
    return 2.0 * math.pi * bound


def radial_slope_bound(waves: Mapping[int, Scalar], samples: int = 2001) -> float:
    """``max over 0 <= rho <= 1`` of ``|d/drho sum_j c_j Z_j(rho)|`` (waves per pupil radius) for
    rotationally symmetric terms (others raise ``ValueError``), on ``samples`` evenly spaced radii
    (a polynomial of low order: the grid maximum is within ~1e-5 of the true one). Floats of the
    values. Times ``lambda / NA`` it is the largest transverse ray aberration the mask causes in
    the focal plane (the geometric blur it adds)."""
    check_rotationally_symmetric(waves)
    best = 0.0
    for i in range(samples):
        rho = i / (samples - 1)
        slope = 0.0
        for j, c in waves.items():
            n, _ = noll_to_nm(j)
            value = float(c.detach()) if isinstance(c, torch.Tensor) else float(c)
            # d/drho of rho^(2p) is 2p rho^(2p - 1)
            d = sum(coef * 2 * p * rho ** (2 * p - 1) for coef, p in _radial_coefficients(n, 0) if p > 0)
            slope += value * math.sqrt(n + 1) * d
        best = max(best, abs(slope))
    return best
