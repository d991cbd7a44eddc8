"""One entry point for scripts: reconstruct a camera frame with a method named by string.

A thin call into :mod:`.registry` (the CLI, the napari plugin and the studio read the same
registry), so "rl-accelerated" means the same everywhere (:func:`accelerated_rl_options`).
"""

from __future__ import annotations

import torch

from lfm_studio.engine.operators.protocol import Projector
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.reconstruct import registry
from lfm_studio.engine.types import OptionValue


def reconstruct_frame(
    projector: Projector,
    frame: torch.Tensor,
    *,
    method: str = "rl",
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
    **options: OptionValue,
) -> torch.Tensor:
    """Volume ``(Z, Y, X)`` from one camera frame ``(Py, Px)`` in photons (baseline removed).

    Parameters
    ----------
    method : a registered method name (:func:`.registry.names`: "rl", "rl-accelerated",
        "wiener", "tikhonov", ...).
    progress, cancel : as in :func:`richardson_lucy_iterates` (iterative methods).
    **options : the method's options (its :class:`~.registry.Option` schema, e.g.
        ``iterations=30, background=2.0`` for RL, ``snr=100.0`` for Wiener); the rest take their
        defaults. An option the method does not take, or a value out of bounds, is a ``ValueError``
        naming it.
    """
    return registry.get(method)(projector, frame, options, progress, cancel)
