"""The conventional-LFM projector per lattice frequency: a small matrix per frequency, and Tikhonov.

:class:`~lfm_studio.engine.operators.lenslet_lattice.LensletLatticeProjector` is a
multi-channel convolution over the lenslet lattice: ``C = Z S^2`` volume channels (depth and
sub-lenslet position) in, ``Q^2`` image channels (pixel position inside a lenslet) out. On a
lattice FFT grid ``(Fy, Fx)`` at least ``(Ly + 2R, Lx + 2R)`` (``R`` the largest reach in
lenslets) the convolution does not wrap, and the projector is exactly

    Y(w) = G(w) X(w),     G(w): a (Q^2 x C) complex matrix per lattice frequency w,

with ``X`` the 2-D DFT of each volume channel and ``Y`` of each image channel (the polyphase
form of a periodically shift-variant system). So the Tikhonov problem
``min ||y - A x||^2 + mu ||x||^2`` on that periodic grid decouples into one small solve per
frequency:

    X(w) = (G^H G + mu I)^-1 G^H Y(w) = G^H (G G^H + mu I)^-1 Y(w),

solved in the smaller of the two dimensions. ``mu`` is relative to ``max_w ||G(w)||_2^2``,
which for non-negative patterns (intensities) is at ``w = 0`` (``|G(w)| <= G(0)``
elementwise, and the spectral norm is monotone in elementwise magnitude for non-negative
matrices): the same scale as the Fourier projector's ``max_k sum_z |H_z(k)|^2``.

As for the shift-invariant closed form (:mod:`lfm_studio.engine.reconstruct.tikhonov`), the
FFT grid is treated as the whole world: the camera only sees ``Ly x Lx`` lenslets of it.

Memory: ``G`` holds ``Fy (Fx//2+1) Q^2 C`` complex numbers, the Tikhonov solver's inverses
``Fy (Fx//2+1) min(Q^2, C)^2`` (0.1 GB and 0.04 GB at 13 x 13 lenslets, 19 px per lenslet, 5
depths, 5 x 5 voxels per lenslet; 2.3 GB together at 26 x 26 lenslets and 32 depths); more than
``max_bytes`` is refused with the size and the fix.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import torch
from torch.nn import functional as nnf

from lfm_studio.engine.dtypes import complex_dtype
from lfm_studio.engine.memory import MemoryBudgetError, format_bytes, require_memory, tensor_bytes
from lfm_studio.engine.operators.fft_sizes import next_fast_length
from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector

MAX_BYTES = 8 * 2**30
"""Largest per-frequency matrix stack built by default (bytes); larger ones are refused."""


@dataclass(frozen=True)
class LatticeLayout:
    """What the transforms need of a lattice projector: ``Q``, ``S``, ``Z``, ``(Ly, Lx)``, device, real dtype."""

    q: int
    s: int
    depths: int
    lenslets: tuple[int, int]
    device: torch.device
    dtype: torch.dtype


class LatticeSpectra:
    """The matrices ``G(w)`` of a :class:`LensletLatticeProjector` on an rfft lattice grid.

    Attributes
    ----------
    grid : ``(Fy, Fx)`` lattice FFT size (lenslets), 2-3-5 smooth, at least ``lenslets + 2R``.
    matrices : ``(Fy, Fx//2+1, Q^2, C)`` complex, ``C = Z S^2`` ordered (depth, sub-position).
    """

    def __init__(self, projector: LensletLatticeProjector, *, max_bytes: int = MAX_BYTES) -> None:
        # The layout, not the projector: a solver kept per projector (weak key) must not hold it.
        self.layout = LatticeLayout(
            projector.q, projector.s, projector.depths, projector.lenslets, projector.device, projector.dtype
        )
        q2 = projector.q * projector.q
        channels = projector.depths * projector.s * projector.s
        reach = max(int(weight.shape[-1]) // 2 for _, weight in projector.groups)
        ly, lx = projector.lenslets
        self.grid = (next_fast_length(ly + 2 * reach), next_fast_length(lx + 2 * reach))
        fy, fx = self.grid
        self.complex = complex_dtype(projector.dtype)
        shape = (fy, fx // 2 + 1, q2, channels)
        smaller = min(q2, channels)
        needed = tensor_bytes(shape, self.complex) + tensor_bytes(
            (*shape[:2], smaller, smaller), self.complex
        )
        what = (f"the per-frequency matrices of the conventional projector {shape} (and the Tikhonov "
                f"solver's {smaller} x {smaller} inverses)")  # fmt: skip
        fix = ("fewer depths or a smaller camera (pixel_count) for this one-step reconstruction, or "
               "Richardson-Lucy, which needs no per-frequency matrices")  # fmt: skip
        if needed > max_bytes:
            raise MemoryBudgetError(
                f"{what} need {format_bytes(needed)}, above max_bytes={format_bytes(max_bytes)}. "
                f"Nothing was allocated. Fix: {fix}, or a larger max_bytes."
            )
        require_memory(needed, what, fix + ".", device=projector.device)
        self.matrices = torch.empty(shape, dtype=self.complex, device=projector.device)
        s2 = projector.s * projector.s
        for indices, weight in projector.groups:
            k = int(weight.shape[-1])
            r = k // 2
            # conv2d correlates: out[j] = sum_t w[t] x[j + t - r], i.e. kernel g[u] = w[r - u].
            rows = (r - torch.arange(k, device=projector.device)) % fy
            cols = (r - torch.arange(k, device=projector.device)) % fx
            for slot, depth in enumerate(indices.tolist()):  # one depth at a time: small temporaries
                kernel = torch.zeros((q2, s2, fy, fx), dtype=projector.dtype, device=projector.device)
                kernel[:, :, rows[:, None], cols[None, :]] = weight[:, slot * s2 : (slot + 1) * s2]
                spectra = torch.fft.rfft2(kernel).permute(2, 3, 0, 1)  # (fy, fx//2+1, q2, s2)
                self.matrices[..., depth * s2 : (depth + 1) * s2] = spectra

    @property
    def channels(self) -> int:
        """``C = Z S^2`` volume channels."""
        return int(self.matrices.shape[-1])

    def peak_gain2(self) -> float:
        """``||G(0)||_2^2``: the largest squared singular value over all frequencies (non-negative patterns)."""
        return float(torch.linalg.matrix_norm(self.matrices[0, 0], ord=2)) ** 2

    def image_spectrum(self, image: torch.Tensor) -> torch.Tensor:
        """Image ``(Ly Q, Lx Q)`` -> channel spectra ``(Fy, Fx//2+1, Q^2)``."""
        p = self.layout
        y = nnf.pixel_unshuffle(image.to(p.device, p.dtype)[None, None], p.q)[0]
        return torch.fft.rfft2(y, s=self.grid).permute(1, 2, 0).contiguous()

    def volume_spectrum(self, volume: torch.Tensor) -> torch.Tensor:
        """Volume ``(Z, Ly S, Lx S)`` -> channel spectra ``(Fy, Fx//2+1, C)`` (the projector's 180-degree turn included)."""
        p = self.layout
        x = nnf.pixel_unshuffle(volume.to(p.device, p.dtype).flip(-2, -1)[None], p.s)[0]
        return (
            torch.fft.rfft2(x.reshape(self.channels, *p.lenslets), s=self.grid).permute(1, 2, 0).contiguous()
        )

    def to_volume(self, spectra: torch.Tensor) -> torch.Tensor:
        """Channel spectra ``(Fy, Fx//2+1, C)`` -> volume ``(Z, Ly S, Lx S)`` (cropped to the lenslets)."""
        p = self.layout
        ly, lx = p.lenslets
        x = torch.fft.irfft2(spectra.permute(2, 0, 1), s=self.grid)[:, :ly, :lx]
        x = x.reshape(p.depths, p.s * p.s, ly, lx)
        return nnf.pixel_shuffle(x, p.s)[:, 0].flip(-2, -1)

    def forward(self, volume: torch.Tensor) -> torch.Tensor:
        """``A x`` evaluated per frequency (equals the projector's convolution; for checks)."""
        p = self.layout
        spectra = (self.matrices @ self.volume_spectrum(volume)[..., None])[..., 0]
        ly, lx = p.lenslets
        y = torch.fft.irfft2(spectra.permute(2, 0, 1), s=self.grid)[:, :ly, :lx]
        return nnf.pixel_shuffle(y[None], p.q)[0, 0]

    def tikhonov(self, mu: float) -> LatticeTikhonov:
        """The closed-form Tikhonov solver for weight ``mu`` (relative to ``||G(0)||_2^2``, > 0)."""
        return LatticeTikhonov(self, mu)


class LatticeTikhonov:
    """``x = (G^H G + mu' I)^-1 G^H y`` per lattice frequency, ``mu' = mu ||G(0)||_2^2``.

    Attributes
    ----------
    weight : ``mu'`` in the projector's units (photons^2 per unit volume^2).

    The closed form is applied as ``(G^H G + mu')^-1 (G^H y)`` or ``G^H ((G G^H + mu')^-1 y)``:
    only ``G`` and the smaller inverses are held, never a ``C x Q^2`` operator.
    """

    def __init__(self, spectra: LatticeSpectra, mu: float) -> None:
        if isinstance(mu, bool) or not (0.0 < float(mu) < float("inf")):
            raise ValueError(
                f"mu must be finite and > 0 for a conventional (lenslet lattice) projector; got {mu!r}. "
                "Fix: e.g. mu=1e-3 (snr=1000); larger for noisier images."
            )
        self.spectra = spectra
        self.mu = float(mu)
        self.weight = self.mu * spectra.peak_gain2()
        g = spectra.matrices
        q2, channels = g.shape[-2:]
        self._small_volume = channels <= q2
        n = channels if self._small_volume else q2
        eye = self.weight * torch.eye(n, dtype=g.dtype, device=g.device)
        rows = []
        for block in g:  # one row of lattice frequencies at a time: bounded temporaries
            gram = adjoint_times(block, block) if self._small_volume else block @ block.mH
            rows.append(torch.linalg.inv(gram + eye))
        self._core = torch.stack(rows)
        """``(G^H G + mu')^-1`` (``C x C``) when ``C <= Q^2``, else ``(G G^H + mu')^-1`` (``Q^2 x Q^2``)."""

    def __call__(self, image: torch.Tensor) -> torch.Tensor:
        """The closed-form volume ``(Z, Ly S, Lx S)`` of ``image`` ``(Ly Q, Lx Q)``."""
        spectra = self.spectra
        y = spectra.image_spectrum(image)[..., None]
        g = spectra.matrices
        # (G^H G + mu')^-1 G^H y, or G^H (G G^H + mu')^-1 y (the push-through identity)
        x = self._core @ adjoint_times(g, y) if self._small_volume else adjoint_times(g, self._core @ y)
        return spectra.to_volume(x[..., 0])

    def precondition(self, volume: torch.Tensor) -> torch.Tensor:
        """``E^T (G^H G + mu')^-1 E v`` on a volume (conjugate-gradient preconditioner; Woodbury when ``C > Q^2``)."""
        spectra = self.spectra
        v = spectra.volume_spectrum(volume)[..., None]
        if self._small_volume:
            return spectra.to_volume((self._core @ v)[..., 0])
        g = spectra.matrices
        inner = adjoint_times(g, self._core @ (g @ v))
        return spectra.to_volume(((v - inner) / self.weight)[..., 0])


def adjoint_times(g: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``G^H v`` as ``conj(G^T conj(v))``: the transpose is a view, so ``G`` is never copied conjugated."""
    return (g.transpose(-1, -2) @ v.conj()).conj()


_SOLVERS: weakref.WeakKeyDictionary[LensletLatticeProjector, LatticeTikhonov] = weakref.WeakKeyDictionary()


def lattice_tikhonov(projector: LensletLatticeProjector, mu: float) -> LatticeTikhonov:
    """The Tikhonov solver of ``projector`` for ``mu``; the last one per projector is kept (a video
    reuses it for every frame). Not kept, and rebuilt with gradients, while the projector's
    patterns require grad under autograd."""
    tracked = torch.is_grad_enabled() and any(weight.requires_grad for _, weight in projector.groups)
    if tracked:
        return LatticeSpectra(projector).tikhonov(mu)
    kept = _SOLVERS.get(projector)
    if kept is None or kept.mu != float(mu):
        spectra = kept.spectra if kept is not None else LatticeSpectra(projector)
        with torch.no_grad():
            kept = spectra.tikhonov(mu)
        _SOLVERS[projector] = kept
    return kept
