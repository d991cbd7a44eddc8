"""One entry point for the apps: reconstruct a camera frame with a method named by string.

The command line (``lfm-studio reconstruct --method``), the napari plugin and scripts
share it, so "rl-accelerated" means the same everywhere (:func:`accelerated_rl_options`).
"""

from __future__ import annotations

import torch

from lfm_studio.engine.operators.protocol import Projector
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.reconstruct.fourier_geometry import require_fourier_projector
from lfm_studio.engine.reconstruct.recommended import accelerated_rl_options
from lfm_studio.engine.reconstruct.richardson_lucy import RLOptions, richardson_lucy
from lfm_studio.engine.reconstruct.tikhonov import tikhonov
from lfm_studio.engine.reconstruct.wiener import wiener

#: Method names and what they run.
METHODS = {
    "rl": "Richardson-Lucy",
    "rl-accelerated": "accelerated Richardson-Lucy (geometric extrapolation with a likelihood safeguard)",
    "wiener": "Wiener deconvolution per depth",
    "tikhonov": "multi-depth Tikhonov per spatial frequency",
}
ITERATIVE = ("rl", "rl-accelerated")


def reconstruct_frame(
    projector: Projector,
    frame: torch.Tensor,
    *,
    method: str = "rl",
    iterations: int = 30,
    background: float = 0.0,
    snr: float | None = None,
    rtol: float | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> torch.Tensor:
    """Volume ``(Z, Y, X)`` from one camera frame ``(Py, Px)`` in counts.

    Parameters
    ----------
    method : one of :data:`METHODS`.
    iterations, rtol : Richardson-Lucy iterations and early-stop tolerance (RL methods).
    background : expected background counts per pixel (RL models it; Wiener and Tikhonov
        subtract it and clip at 0).
    snr : Wiener power SNR (default 100); Tikhonov uses ``mu = 1 / snr`` (default 1e-3).
    progress, cancel : as in :func:`richardson_lucy_iterates` (RL methods).
    """
    if method not in METHODS:
        raise ValueError(
            f"method must be one of {list(METHODS)}; got {method!r}. Fix: e.g. 'rl-accelerated'."
        )
    if method in ITERATIVE:
        options: RLOptions = {
            "background": background, "iterations": iterations, "rtol": rtol,
            "progress": progress, "cancel": cancel,
        }  # fmt: skip
        if method == "rl-accelerated":
            options.update(accelerated_rl_options(projector))
        return richardson_lucy(projector, frame, **options)
    signal = (frame - background).clamp_min(0.0)
    if method == "wiener":
        fourier = require_fourier_projector(projector, "Wiener deconvolution")
        return wiener(fourier, signal) if snr is None else wiener(fourier, signal, snr=snr)
    fourier = require_fourier_projector(projector, "Tikhonov reconstruction")
    return tikhonov(fourier, signal) if snr is None else tikhonov(fourier, signal, mu=1.0 / snr)
