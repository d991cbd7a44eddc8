"""Structural similarity (SSIM) in 2D and 3D with a Gaussian window (Wang et al. 2004).

Definition (Wang, Bovik, Sheikh & Simoncelli, IEEE TIP 13, 600-612, 2004): with local
means ``mu``, variances ``s^2`` and covariance ``s_xy`` taken under a Gaussian window,

    SSIM = (2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_x^2 + s_y^2 + C2)),
    C1 = (K1 R)^2, C2 = (K2 R)^2, K1 = 0.01, K2 = 0.03, R = data range,

and the reported value is the mean of this map. Conventions (identical to
``skimage.metrics.structural_similarity(gaussian_weights=True, sigma=1.5,
use_sample_covariance=False, data_range=R)``, tested against it): separable Gaussian
of ``sigma = 1.5`` samples truncated at ``3.5 sigma`` (an 11-tap window, radius
``r = int(3.5 sigma + 0.5)``), population (not sample) covariances, edges handled by
half-sample symmetric reflection (scipy's ``mode="reflect"``), and the mean taken
after cropping ``r`` samples from every side of each filtered axis.

``sigma`` may be one value per axis; ``0`` along an axis means no smoothing and no
cropping along it (e.g. ``(0, 1.5, 1.5)`` treats a volume as a stack of 2D images
that are averaged together).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from lfm_studio.engine.image_quality.basic import as_pair, data_range_of

TRUNCATE = 3.5
"""Gaussian truncation in standard deviations (scikit-image's choice for an 11-tap window at sigma 1.5)."""
K1, K2 = 0.01, 0.03
"""Stabilising constants of Wang et al. 2004."""


def _sigmas(sigma: float | Sequence[float], ndim: int) -> tuple[float, ...]:
    values = tuple(float(s) for s in sigma) if isinstance(sigma, Sequence) else (float(sigma),) * ndim
    if len(values) != ndim or any(not (s >= 0) for s in values):
        raise ValueError(
            f"sigma must be a number >= 0 (samples) or one per axis ({ndim} values); got {sigma!r}."
        )
    return values


def window_radius(sigma: float, truncate: float) -> int:
    return int(truncate * sigma + 0.5)  # scipy.ndimage's radius


def _kernel(sigma: float, radius: int, device: torch.device) -> torch.Tensor:
    x = torch.arange(-radius, radius + 1, dtype=torch.float64, device=device)
    weights = torch.exp(-0.5 * (x / sigma) ** 2)
    return weights / weights.sum()


def _reflect_indices(n: int, radius: int, device: torch.device) -> torch.Tensor:
    """Indices of ``arange(-radius, n + radius)`` folded by half-sample symmetry (``d c b a | a b c d``)."""
    index = torch.arange(-radius, n + radius, device=device) % (2 * n)
    return torch.where(index >= n, 2 * n - 1 - index, index)


def gaussian_filter(
    x: torch.Tensor, sigma: float | Sequence[float], *, truncate: float = TRUNCATE, axes: int | None = None
) -> torch.Tensor:
    """Separable Gaussian smoothing of the last ``axes`` dimensions (default all), reflect edges.

    Matches ``scipy.ndimage.gaussian_filter(x, sigma, mode="reflect", truncate=truncate)``;
    ``sigma`` in samples, one value or one per filtered axis (``0`` leaves an axis alone).
    Leading dimensions beyond ``axes`` are a batch.
    """
    axes = x.ndim if axes is None else axes
    sigmas = _sigmas(sigma, axes)
    for offset, s in enumerate(sigmas):
        if s == 0:
            continue
        dim = x.ndim - axes + offset
        n, radius = x.shape[dim], window_radius(s, truncate)
        padded = x.index_select(dim, _reflect_indices(n, radius, x.device))
        weights = _kernel(s, radius, torch.device("cpu")).tolist()
        # A weighted sum of 2 r + 1 shifted views: about 10x faster on the CPU than a
        # one-channel float64 conv1d (no im2col), and the same sums.
        out = padded.narrow(dim, 0, n) * weights[0]
        for k in range(1, len(weights)):
            out.add_(padded.narrow(dim, k, n), alpha=weights[k])
        x = out
    return x


def ssim_map(
    truth,
    estimate,
    *,
    data_range: float | None = None,
    sigma: float | Sequence[float] = 1.5,
    truncate: float = TRUNCATE,
    k1: float = K1,
    k2: float = K2,
) -> torch.Tensor:
    """The local SSIM map (float64, the inputs' shape, edges not yet cropped); see :func:`ssim`."""
    truth, estimate = as_pair(truth, estimate, name="ssim")
    if truth.ndim not in (2, 3):
        raise ValueError(
            f"ssim compares images (Y, X) or volumes (Z, Y, X); got shape {tuple(truth.shape)}. "
            "Fix: compare one frame at a time."
        )
    if not (k1 >= 0 and k2 >= 0):
        raise ValueError(f"k1 and k2 must be >= 0; got k1={k1!r}, k2={k2!r}.")
    sigmas = _sigmas(sigma, truth.ndim)
    for axis, (n, s) in enumerate(zip(truth.shape, sigmas, strict=True)):
        window = 2 * window_radius(s, truncate) + 1
        if s > 0 and n < window:
            name = "ZYX"[axis - truth.ndim]
            raise ValueError(
                f"ssim: axis {name} has {n} samples, fewer than the {window}-sample Gaussian window "
                f"(sigma {s:g} samples, truncated at {truncate:g} sigma). Fix: pass sigma=0 for that axis "
                "(e.g. sigma=(0, 1.5, 1.5) for a volume with few depths), or use per-depth curves."
            )
    r = data_range_of(truth, data_range)
    c1, c2 = (k1 * r) ** 2, (k2 * r) ** 2
    value = estimate.reshape(-1)[0]
    if not estimate.requires_grad and bool((estimate == value).all()):
        # A constant estimate (e.g. the all-zero floor): its local mean is the constant and its
        # variance and covariance with the truth are 0, so only the truth's moments are filtered.
        mu_t, tt = gaussian_filter(
            torch.stack((truth, truth * truth)), sigmas, truncate=truncate, axes=truth.ndim
        )
        mu_e, var_t = torch.full_like(mu_t, float(value)), tt - mu_t * mu_t
        var_e = cov = torch.zeros_like(mu_t)
    else:
        stacked = torch.stack((truth, estimate, truth * truth, estimate * estimate, truth * estimate))
        mu_t, mu_e, tt, ee, te = gaussian_filter(stacked, sigmas, truncate=truncate, axes=truth.ndim)
        var_t, var_e, cov = tt - mu_t * mu_t, ee - mu_e * mu_e, te - mu_t * mu_e
    numerator = (2 * mu_t * mu_e + c1) * (2 * cov + c2)
    denominator = (mu_t * mu_t + mu_e * mu_e + c1) * (var_t + var_e + c2)
    return numerator / denominator


def ssim(
    truth,
    estimate,
    *,
    data_range: float | None = None,
    sigma: float | Sequence[float] = 1.5,
    truncate: float = TRUNCATE,
    k1: float = K1,
    k2: float = K2,
) -> torch.Tensor:
    """Mean structural similarity of ``estimate`` to ``truth``, 2D ``(Y, X)`` or 3D ``(Z, Y, X)``.

    Parameters
    ----------
    truth, estimate : real tensors or arrays of one shape, 2D or 3D.
    data_range : float, optional
        ``R`` of ``C1 = (K1 R)^2, C2 = (K2 R)^2``; default the truth's ``max - min``.
    sigma : float or one per axis
        Gaussian window width in samples (default 1.5 along every axis, Wang et al.);
        each filtered axis needs at least ``2 int(truncate sigma + 0.5) + 1`` samples
        (11 at the default), else a ``ValueError`` says what to pass instead.
    truncate, k1, k2 : window truncation (sigmas) and the SSIM constants (0.01, 0.03).

    Returns
    -------
    0-d float64 tensor in ``[-1, 1]``; exactly 1 for identical inputs.
    """
    full = ssim_map(truth, estimate, data_range=data_range, sigma=sigma, truncate=truncate, k1=k1, k2=k2)
    sigmas = _sigmas(sigma, full.ndim)
    index = tuple(
        slice(r, n - r) if s > 0 else slice(None)
        for n, s, r in ((n, s, window_radius(s, truncate)) for n, s in zip(full.shape, sigmas, strict=True))
    )
    return full[index].mean()
