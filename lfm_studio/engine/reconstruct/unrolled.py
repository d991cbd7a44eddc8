"""Richardson-Lucy unrolled for a fixed number of iterations: a differentiable reconstruction.

Plain multiplicative updates (Richardson 1972, Lucy 1974)::

    x_{k+1} = x_k * max(A^T(y / max(A x_k, f)), 0) / max(A^T 1, g)

(``f``, ``g``: the production solver's floors, :func:`rl_ratio`)

with no safeguards, stopping rules or in-place writes, so gradients flow from the
result to the image, the start volume and, through the projector, to the PSF and the
optics it came from (end-to-end design studies, learned unrolled solvers). The
production solver with its checks is :mod:`~lfm_studio.engine.reconstruct.richardson_lucy`.
"""

from __future__ import annotations

from typing import Protocol

import torch

from lfm_studio.engine.reconstruct.guards import relative_floor


class _Projector(Protocol):
    @property
    def volume_shape(self) -> tuple[int, int, int]: ...

    def forward(self, volume: torch.Tensor) -> torch.Tensor: ...

    def adjoint(self, image: torch.Tensor) -> torch.Tensor: ...


def richardson_lucy_unrolled(
    projector: _Projector,
    image: torch.Tensor,
    iterations: int,
    *,
    initial: torch.Tensor | None = None,
    eps: float = 1e-12,
) -> torch.Tensor:
    """``iterations`` Richardson-Lucy updates of ``initial`` for ``image``; differentiable.

    Parameters
    ----------
    projector : any projector with ``forward`` (volume -> image), ``adjoint`` and ``volume_shape``.
    image : non-negative camera image (the projector's image shape), photons or W.
    iterations : number of updates (>= 0; 0 returns the start volume).
    initial : start volume (positive, the projector's volume shape); default the flat
        volume whose projection carries the image's total signal.
    eps : the smallest floor of the denominators (same unit as they are; :func:`rl_ratio`), keeps
        them non-zero for an all-zero image.

    Returns
    -------
    Volume ``(Z, Vy, Vx)`` in the projector's dtype.
    """
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 0:
        raise ValueError(f"iterations must be an integer >= 0; got {iterations!r}. Fix: use e.g. 3.")
    if not eps > 0:
        raise ValueError(f"eps must be > 0; got {eps!r}. Fix: use 1e-12.")
    sensitivity = projector.adjoint(torch.ones_like(image))
    if initial is None:
        ones = torch.ones(projector.volume_shape, dtype=sensitivity.dtype, device=sensitivity.device)
        initial = ones * (image.sum() / (projector.forward(ones).sum() + eps))
    if tuple(initial.shape) != tuple(projector.volume_shape):
        raise ValueError(
            f"initial must have the projector's volume shape {tuple(projector.volume_shape)}; "
            f"got {tuple(initial.shape)}."
        )
    volume = initial
    for _ in range(iterations):
        volume = volume * rl_ratio(projector, image, volume, sensitivity, eps=eps)
    return volume


def rl_ratio(
    projector: _Projector,
    image: torch.Tensor,
    volume: torch.Tensor,
    sensitivity: torch.Tensor,
    *,
    background: float | torch.Tensor = 0.0,
    eps: float = 1e-12,
) -> torch.Tensor:
    """The Richardson-Lucy update factor ``max(A^T(y / max(A x + b, f)), 0) / max(A^T 1, g)``
    (differentiable): one plain RL step is ``x * rl_ratio(...)``; learned unrolled solvers reshape it
    (an exponent, a correction) between steps. ``sensitivity`` is ``A^T 1``, computed once by the caller.

    The floors are those of the production solver (:mod:`.richardson_lucy`): ``f`` is ``16 eps`` of
    the dtype times the image's largest value, ``g`` the same of the sensitivity's (each at least
    ``eps``, in the same unit). Without ``f``, a pixel with counts (read noise) where the model
    predicts no light, ``A x`` a rounding error, gave a ratio of ``y / eps`` and volumes of 1e29 on
    a 2048^2 light field. The back-projected ratio is clipped at 0 (FFT rounding)."""
    floor = relative_floor(sensitivity.dtype)
    predicted = (projector.forward(volume) + background).clamp_min(
        max(floor * float(image.detach().max()), eps)
    )
    denominator = sensitivity.clamp_min(max(floor * float(sensitivity.detach().max()), eps))
    return projector.adjoint(image / predicted).clamp_min(0.0) / denominator
