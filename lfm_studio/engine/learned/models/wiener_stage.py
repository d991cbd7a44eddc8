"""MultiWienerNet's learnable Wiener stage, applied at the cost of one adjoint ``A^T``.

Depth ``z`` of the stage is ``crop(F^-1[g_z(|k|) conj(H_z) Y / (|H_z|^2 + M_z^2 / SNR_z)])``
on the projector's FFT window (``H_z`` its OTF, ``M_z`` the OTF peak, ``Y`` the image spectrum;
:mod:`lfm_studio.engine.reconstruct.wiener` with ``g_z = 1``). The radial gain ``g_z`` is
piecewise linear in ``|k|`` between ``bins`` control points from DC to the highest frequency,
written here as ``gain (Z, bins) @ basis (bins, K)`` with hat functions ``basis`` fixed at
construction, so all depths' filters are one matrix product and three elementwise passes.

A :class:`~lfm_studio.engine.operators.protocol.PrunedFourierProjector` (the
:class:`~lfm_studio.engine.operators.ShiftInvariantProjector`) applies the filters through its
pruned transforms (:meth:`filtered_adjoint`: only the volume's rows and columns of each depth are
inverse-transformed), in its transposed spectra layout ``(Z, Fx//2+1, Fy)``; any other Fourier
projector through :func:`~lfm_studio.engine.reconstruct.fourier_geometry.filter_to_volume` (full
inverse transforms, rfft2 layout ``(Z, Fy, Fx//2+1)``). Both compute the same volume.
"""

from __future__ import annotations

import torch

from lfm_studio.engine.operators.protocol import FourierProjector, PrunedFourierProjector
from lfm_studio.engine.reconstruct.fourier_geometry import (
    filter_to_volume,
    image_spectrum,
    otf_peaks,
    radial_frequency,
)


def check_bins(bins: int) -> int:
    """``bins`` as the number of radial control points (an integer >= 2), or a ValueError."""
    if isinstance(bins, bool) or not isinstance(bins, int) or bins < 2:
        raise ValueError(f"bins must be an integer >= 2 (radial gain control points); got {bins!r}.")
    return bins


class WienerGeometry:
    """What the stage's filters are built from, fixed per projector (no parameters).

    Attributes
    ----------
    spectra : the OTFs ``(Z, A, B)`` in the layout the stage filters in (``otf_t`` when pruned,
        else ``otf``), complex, the projector's dtype.
    power : ``|spectra|^2`` ``(Z, A, B)``, real.
    peaks2 : squared OTF peak per depth ``(Z,)`` (the DC gain squared; photons^2 per unit volume).
    basis : hat functions ``(bins, A * B)`` of the radial position ``|k| / max|k| * (bins - 1)``.
    pruned : whether :meth:`apply` runs through the projector's pruned ``filtered_adjoint``.
    """

    def __init__(self, projector: FourierProjector, bins: int) -> None:
        self.projector = projector
        self.pruned = isinstance(projector, PrunedFourierProjector)
        spectra = projector.otf_t if isinstance(projector, PrunedFourierProjector) else projector.otf
        self.spectra = spectra.detach()
        dtype = self.spectra.real.dtype
        self.power = self.spectra.real.square() + self.spectra.imag.square()
        self.peaks2 = otf_peaks(projector).detach().to(dtype) ** 2
        frequency = radial_frequency(projector)  # (Fy, Fx//2+1), cycles per pixel, float64
        if self.pruned:
            frequency = frequency.T
        position = (frequency / frequency.max() * (check_bins(bins) - 1)).reshape(1, -1)
        controls = torch.arange(bins, dtype=position.dtype, device=position.device)[:, None]
        self.basis = (1.0 - (position - controls).abs()).clamp_min(0.0).to(dtype)

    def filters(self, log_snr: torch.Tensor, radial_gain: torch.Tensor) -> torch.Tensor:
        """Per-depth filters ``g_z conj(H_z) / (|H_z|^2 + M_z^2 exp(-log_snr_z))``, shape of :attr:`spectra`.

        ``log_snr`` ``(Z,)`` and ``radial_gain`` ``(Z, bins)`` are dimensionless (differentiable).
        """
        radial = (radial_gain @ self.basis).reshape(self.power.shape)
        regulariser = (self.peaks2 * torch.exp(-log_snr))[:, None, None]
        return self.spectra.conj() * (radial / (self.power + regulariser))

    def apply(self, image: torch.Tensor, filters: torch.Tensor) -> torch.Tensor:
        """The volume ``(Z, Vy, Vx)`` of ``filters`` (from :meth:`filters`) applied to ``image`` ``(Py, Px)``."""
        if isinstance(self.projector, PrunedFourierProjector):
            return self.projector.filtered_adjoint(image, filters)
        return filter_to_volume(self.projector, image_spectrum(self.projector, image), filters)
