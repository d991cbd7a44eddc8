"""Multi-depth Tikhonov reconstruction for the shift-invariant (Fourier LFM) model, per spatial frequency.

Model on the projector's FFT window (periodic there; the window is large enough that
the convolution does not wrap): ``Y(k) = sum_z H_z(k) X_z(k) = H_k^T x_k`` with
``H_k = (H_1(k), ..., H_Z(k))`` the OTF values of all depths at frequency ``k``. The
Tikhonov problem ``min ||Y - H_k^T x_k||^2 + mu ||x_k||^2`` decouples over ``k`` into
``(conj(H_k) H_k^T + mu I) x_k = conj(H_k) Y(k)``: a rank-one update of ``mu I``.
Sherman-Morrison with ``u = conj(H_k)``: ``(mu I + u u^H) u = u (mu + u^H u)``, so

    x_k = conj(H_k) Y(k) / (|H_k|^2 + mu),     |H_k|^2 = sum_z |H_z(k)|^2,

one division per frequency instead of a ``Z x Z`` solve. ``mu`` is given relative to
``max_k |H_k|^2`` (dimensionless, independent of the PSF normalisation); ``mu = 0``
gives the minimum-norm least-squares (pseudo-inverse) solution, with frequencies where
``|H_k| <= 16 eps max|H_k|`` set to 0. The image is embedded in the FFT window as the
projector's adjoint embeds it and each depth is cropped to the volume as the adjoint
crops it.

The closed form treats the FFT window as the whole world: it ignores that the camera
sees only its own window of the full convolution and that the volume is smaller than
the window. ``refine=N`` runs ``N`` preconditioned conjugate-gradient steps on the exact
normal equations of the projector, ``(A^T A + mu I) x = A^T y``, preconditioned by the
per-frequency inverse ``(conj(H) H^T + mu)^-1 = (I - u u^H / (mu + |u|^2)) / mu`` (needs
``mu > 0``); it converges to the exact Tikhonov solution of the projector's model.

A conventional-LFM projector (:class:`~lfm_studio.engine.operators.lenslet_lattice.LensletLatticeProjector`)
is periodic in the lenslet lattice rather than shift-invariant: per lattice frequency it is a
small matrix (:mod:`lfm_studio.engine.operators.lattice_spectra`), and the same closed form is a
small linear solve per frequency (``mu > 0``, relative to ``max ||G(w)||_2^2``); ``refine``
preconditions with that per-frequency inverse.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from lfm_studio.engine.operators.lattice_spectra import lattice_tikhonov
from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector
from lfm_studio.engine.operators.protocol import FourierProjector, Projector, PrunedFourierProjector
from lfm_studio.engine.reconstruct.fourier_geometry import (
    depth_chunks,
    filter_to_volume,
    image_spectrum,
    require_fourier_projector,
    spectra_to_volume,
    volume_spectrum,
)
from lfm_studio.engine.reconstruct.guards import check_image, relative_floor
from lfm_studio.engine.types import TensorLike


def otf_power(projector: FourierProjector) -> torch.Tensor:
    """``|H_k|^2 = sum_z |H_z(k)|^2`` on the rfft grid ``(Fy, Fx//2+1)``, float64.

    Reads the contiguous transposed spectra ``otf_t`` of a :class:`PrunedFourierProjector` (a
    strided pass over the ``otf`` view was 5x slower) and returns a transposed view then.
    """
    transposed = isinstance(projector, PrunedFourierProjector)
    spectra = projector.otf_t if isinstance(projector, PrunedFourierProjector) else projector.otf
    total: torch.Tensor | None = None
    for part in depth_chunks(projector):
        h = spectra[part]
        term = (h.real.square() + h.imag.square()).sum(dim=0).double()  # squares in the OTF's precision
        total = term if total is None else total + term
    assert total is not None  # at least one depth
    return total.transpose(0, 1) if transposed else total


def check_mu(mu: float, *, refine: int) -> float:
    """``mu`` >= 0 (> 0 when refining), finite."""
    value = float(mu)
    if not (0.0 <= value < float("inf")) or (refine and value == 0.0):
        limit = "> 0 when refine > 0" if refine else ">= 0"
        raise ValueError(
            f"mu must be finite and {limit} (relative to max_k sum_z |H_z(k)|^2); got {mu!r}. "
            "Fix: e.g. mu=1e-3; larger for noisier images."
        )
    return value


def tikhonov(projector: Projector, image: TensorLike, *, mu: float = 1e-3, refine: int = 0) -> torch.Tensor:
    """Multi-depth Tikhonov reconstruction ``(Z, Vy, Vx)`` of ``image``.

    Parameters
    ----------
    projector : FourierProjector or LensletLatticeProjector
        Cached OTFs (e.g. ShiftInvariantProjector), or a conventional-LFM lattice projector (then
        ``mu > 0``); any other projector raises ``NotImplementedError``.
    image : tensor or array ``(Py, Px)``
        Camera image in photons, the camera's baseline removed (finite; negative noise values are
        fine): convert camera counts with :func:`lfm_studio.engine.io.counts_to_photons`.
    mu : float
        Regularisation weight relative to ``max_k |H_k|^2`` (>= 0).
    refine : int
        Conjugate-gradient steps on the projector's exact normal equations (0: closed form only).
        Each costs about two RL iterations and keeps ``Z`` spectra in memory.
    """
    if isinstance(refine, bool) or not isinstance(refine, int) or refine < 0:
        raise ValueError(f"refine must be an int >= 0 (conjugate-gradient steps); got {refine!r}.")
    if isinstance(projector, LensletLatticeProjector):
        y = check_image(
            image, projector.image_shape, dtype=projector.dtype, device=projector.device, non_negative=False
        )  # before the solver: a bad image costs no per-frequency solves
        solver = lattice_tikhonov(projector, mu)  # mu > 0, checked there
        x = solver(y)
        return _refine(projector, y, x, solver.weight, solver.precondition, refine) if refine else x
    projector = require_fourier_projector(projector, "Tikhonov reconstruction")
    mu = check_mu(mu, refine=refine)
    otf = projector.otf
    dtype = otf.real.dtype
    y = check_image(image, projector.image_shape, dtype=dtype, device=otf.device, non_negative=False)
    power = otf_power(projector)
    peak = float(power.max())
    mu_abs = mu * peak
    denominator = power + mu_abs
    keep = denominator > relative_floor(dtype) ** 2 * peak
    gain = torch.where(keep, 1.0 / torch.where(keep, denominator, 1.0), 0.0).to(dtype)
    spectrum = image_spectrum(projector, y) * gain
    x = filter_to_volume(projector, spectrum, lambda part: otf[part].conj())
    if refine:
        x = _refine(projector, y, x, mu_abs, lambda r: _precondition(projector, r, mu_abs, power), refine)
    return x


def _precondition(
    projector: FourierProjector, residual: torch.Tensor, mu: float, power: torch.Tensor
) -> torch.Tensor:
    """``E^T (conj(H) H^T + mu)^-1 E r``: the per-frequency Sherman-Morrison inverse on a volume."""
    spectra = volume_spectrum(projector, residual)
    otf = projector.otf
    along = (otf * spectra).sum(dim=0)  # H_k^T r_k
    inverse = (spectra - otf.conj() * (along / (mu + power)).to(spectra.dtype)) / mu
    return spectra_to_volume(projector, inverse)


def _refine(
    projector: Projector,
    y: torch.Tensor,
    x: torch.Tensor,
    mu: float,
    precondition: Callable[[torch.Tensor], torch.Tensor],
    steps: int,
) -> torch.Tensor:
    """CG on ``(A^T A + mu I) x = A^T y`` from ``x``, preconditioned by ``precondition`` (volume -> volume)."""

    def normal(v: torch.Tensor) -> torch.Tensor:
        return projector.adjoint(projector.forward(v)) + mu * v

    def dot(a: torch.Tensor, b: torch.Tensor) -> float:
        return float((a.double() * b.double()).sum())

    rhs = projector.adjoint(y)
    residual = rhs - normal(x)
    z = precondition(residual)
    direction, rz = z, dot(residual, z)
    stop = (relative_floor(x.dtype) * float(torch.linalg.vector_norm(rhs.double()))) ** 2
    for _ in range(steps):
        if dot(residual, residual) <= stop or rz <= 0:
            break
        applied = normal(direction)
        step = rz / dot(direction, applied)
        x = x + step * direction
        residual = residual - step * applied
        z = precondition(residual)
        rz, previous = dot(residual, z), rz
        direction = z + (rz / previous) * direction
    return x
