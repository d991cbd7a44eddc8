"""What one frame's reconstruction runs: a registered method and its options, validated once, small and picklable."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import torch

from lfm_studio.engine.operators.protocol import Projector
from lfm_studio.engine.reconstruct import registry
from lfm_studio.engine.types import JSONValue, OptionValue


@dataclass(frozen=True)
class ReconstructionOptions:
    """A method of the reconstruction registry and its options, checked against its schema.

    ``options`` are stored as sorted ``(name, value)`` pairs (hashable, picklable: they travel to the
    Dask workers), completed with the method's defaults. ``background`` is in photons per pixel;
    the camera's noise floor is added per frame when counts are converted.
    """

    method: str = "rl-accelerated"
    options: tuple[tuple[str, OptionValue], ...] = ()

    @classmethod
    def of(cls, method: str, options: Mapping[str, OptionValue] | None = None) -> ReconstructionOptions:
        """``method`` with ``options`` resolved by the registry (named errors for unknown or bad ones)."""
        resolved = registry.get(method).resolve(dict(options or {}))
        return cls(method, tuple(sorted(resolved.items())))

    def to_dict(self) -> dict[str, JSONValue]:
        """JSON-ready record (stored in the output's metadata)."""
        return {"method": self.method, **dict(self.options)}

    def run(
        self, projector: Projector, frame: torch.Tensor, *, extra_background: float = 0.0
    ) -> torch.Tensor:
        """The volume ``(Z, Y, X)`` of one frame ``(Py, Px)``; ``extra_background``: the camera's floor."""
        options = dict(self.options)
        background = options.get("background", 0.0)
        options["background"] = (
            float(background if isinstance(background, (int, float)) else 0.0) + extra_background
        )
        return registry.get(self.method)(projector, frame, options)
