"""What one frame's reconstruction runs: method and options, validated once, small and picklable."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import torch

from lfm_studio.engine.reconstruct.dispatch import ITERATIVE, METHODS, reconstruct_frame


@dataclass(frozen=True)
class ReconstructionOptions:
    """Arguments of :func:`~lfm_studio.engine.reconstruct.dispatch.reconstruct_frame` for every frame.

    ``background`` is in photons per pixel (the camera's noise floor is added per frame when
    counts are converted); ``snr`` is Wiener's power SNR (Tikhonov: ``mu = 1 / snr``).
    """

    method: str = "rl-accelerated"
    iterations: int = 30
    background: float = 0.0
    snr: float | None = None
    rtol: float | None = None

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(
                f"method must be one of {list(METHODS)}; got {self.method!r}. Fix: e.g. 'rl-accelerated'."
            )
        if isinstance(self.iterations, bool) or not isinstance(self.iterations, int) or self.iterations < 1:
            raise ValueError(f"iterations must be an integer >= 1; got {self.iterations!r}. Fix: e.g. 30.")
        if not (math.isfinite(self.background) and self.background >= 0):
            raise ValueError(
                f"background must be a finite number >= 0 (photons per pixel); got {self.background!r}."
            )
        if self.snr is not None and not (math.isfinite(self.snr) and self.snr > 0):
            raise ValueError(f"snr must be a finite number > 0; got {self.snr!r}. Fix: e.g. 100.")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record (stored in the output's metadata); ``iterations`` is None for direct methods."""
        record = asdict(self)
        if self.method not in ITERATIVE:
            record["iterations"] = None
        return record

    def run(self, projector: Any, frame: torch.Tensor, *, extra_background: float = 0.0) -> torch.Tensor:
        """The volume ``(Z, Y, X)`` of one frame ``(Py, Px)``; ``extra_background``: the camera's floor."""
        return reconstruct_frame(
            projector, frame, method=self.method, iterations=self.iterations,
            background=self.background + extra_background, snr=self.snr, rtol=self.rtol,
        )  # fmt: skip
