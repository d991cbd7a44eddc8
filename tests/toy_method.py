"""A toy reconstruction method for registry tests: "backprojection", the normalised adjoint.

``x = A^T (y - b)_+ / A^T 1`` (one step, any projector). :func:`registered` adds it to the
registry for the duration of a ``with`` block, so every front end built inside sees it.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch

from lfm_studio.engine.progress import checkpoint
from lfm_studio.engine.reconstruct import registry

NAME = "backprojection"
SCALE = registry.Option("scale", float, 1.0, "scale of the result", minimum=0.0, exclusive_minimum=True)


def backprojection(projector, frame, options, progress, cancel) -> torch.Tensor:
    checkpoint(cancel, progress, 0, 1, "back projecting")
    signal = (frame - options["background"]).clamp_min(0.0)
    sensitivity = projector.adjoint(torch.ones_like(signal))
    volume = projector.adjoint(signal) / sensitivity.clamp_min(1e-12 * float(sensitivity.max()))
    checkpoint(cancel, progress, 1, 1, "done")
    return options["scale"] * volume


METHOD = registry.Method(
    NAME,
    "Back projection (toy)",
    "normalised adjoint A^T (y - b) / A^T 1, one step",
    (SCALE,),
    backprojection,
    differentiable=True,
)


@contextmanager
def registered() -> Iterator[registry.Method]:
    """The toy method, registered until the block ends."""
    method = registry.register(METHOD)
    try:
        yield method
    finally:
        registry.unregister(NAME)
