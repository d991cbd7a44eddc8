"""Wiener deconvolution per depth (thesis eq. 4.5) for a shift-invariant (Fourier LFM) projector.

Eq. 4.5, ``O = F^-1[ 1 / (1 + 1 / (|H|^2 SNR)) * Y / H ]``, is the same as

    X_z(k) = conj(H_z(k)) Y(k) / (|H_z(k)|^2 + M_z^2 / SNR)

with ``H_z`` the OTF of depth ``z`` (the projector's cached ``otf``), ``Y`` the spectrum
of the image embedded in the projector's FFT window exactly as its adjoint embeds it,
and the result cropped to the volume grid as the adjoint crops it. ``SNR`` is the
power signal-to-noise ratio *relative to the OTF peak* ``M_z`` (the DC gain, the
PSF sum), so it does not depend on how the PSF is normalised: the filter of a depth
is ``F^-1[conj(h) Y / (|h|^2 + 1/SNR)] / M_z`` with ``h = H_z / M_z``.

Each depth is deconvolved on its own from the whole image (a "refocused and
deconvolved" stack; out-of-focus light from the other depths is not removed, which
is what 3D Richardson-Lucy or :func:`.tikhonov` do). A *view* (one lenslet's
sub-image) is deconvolved the same way with a projector built from that view's PSF.

Not photons per voxel, and a preview only: every depth is reconstructed as if all the light came
from it, so each slice holds about the image's photons over that depth's PSF sum (the whole
truth's photons) and the volume several times the truth's (3.3x at the default SNR on 5 depths
of the bead sample), with the other depths' light as halos and false peaks. On that sample NCC
is 0.31 and bead F1 0.23 where RL-30 gives 0.84 and 1.00, and its SSIM (0.945) is below the
all-zero volume's (0.986); the noise-free image scores the same. For quantitative work use
Richardson-Lucy, or :func:`.tikhonov` for one step (docs/reconstruction_methods.md, "Wiener").

Limits: ``SNR -> 0`` gives 0; ``SNR = inf`` gives the pseudo-inverse ``Y / H_z``
where ``|H_z| > 16 eps M_z`` and 0 elsewhere (the same threshold guards the finite-SNR
division, so the two agree as SNR grows).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math

import torch

from lfm_studio.engine.operators.protocol import FourierProjector
from lfm_studio.engine.reconstruct.fourier_geometry import (
    filter_to_volume,
    image_spectrum,
    otf_peaks,
    require_fourier_projector,
)
from lfm_studio.engine.reconstruct.guards import check_image, relative_floor
from lfm_studio.engine.types import DepthSlice, TensorLike


def check_snr(snr: float) -> float:
    """``snr`` as a float > 0 (``math.inf`` allowed: the pseudo-inverse)."""
    value = float(snr)
    if not value > 0 or math.isnan(value):
        raise ValueError(
            f"snr must be > 0 (power signal-to-noise ratio, dimensionless; inf for the pseudo-inverse); "
            f"got {snr!r}. Fix: e.g. snr=100 for a clean image, 1 to 10 for a noisy one."
        )
    return value


def wiener(projector: FourierProjector, image: TensorLike, *, snr: float = 100.0) -> torch.Tensor:
    """Wiener deconvolution of ``image`` at every depth of a shift-invariant ``projector``.

    Parameters
    ----------
    projector : FourierProjector
        Fourier LFM projector (cached OTFs, e.g. ShiftInvariantProjector); its dtype and device
        are used. Any other projector raises ``NotImplementedError``.
    image : tensor or array ``(Py, Px)``
        Camera image in photons, the camera's baseline removed (finite; a linear method, so
        zero-mean noise may be negative): convert camera counts with
        :func:`lfm_studio.engine.io.counts_to_photons`.
    snr : float
        Power SNR relative to the OTF peak (> 0, ``math.inf`` for the pseudo-inverse).

    Returns
    -------
    tensor ``(Z, Vy, Vx)``
        One deconvolved slice per depth, on the projector's volume grid. Each slice carries about
        the whole image's light (not photons per voxel; see the module docstring): a preview, not
        a quantitative reconstruction.
    """
    projector = require_fourier_projector(projector, "Wiener deconvolution")
    snr = check_snr(snr)
    otf = projector.otf
    dtype = otf.real.dtype
    y = check_image(image, projector.image_shape, dtype=dtype, device=otf.device, non_negative=False)
    peaks2 = otf_peaks(projector).double() ** 2  # (Z,)
    threshold2 = (relative_floor(dtype) ** 2 * peaks2)[:, None, None]
    regulariser = (peaks2 / snr)[:, None, None] if math.isfinite(snr) else torch.zeros_like(threshold2)

    def filters(part: DepthSlice) -> torch.Tensor:
        h = otf[part]
        denominator = h.real.double() ** 2 + h.imag.double() ** 2 + regulariser[part]
        keep = denominator > threshold2[part]
        gain = torch.where(keep, 1.0 / torch.where(keep, denominator, 1.0), 0.0).to(dtype)
        return h.conj() * gain

    return filter_to_volume(projector, image_spectrum(projector, y), filters)
