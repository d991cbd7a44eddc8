"""The learned reconstructors: unrolled Richardson-Lucy (default), MultiWienerNet, blind U-Net.

Each is a ``torch.nn.Module`` built as ``Model(projector, **config)``; ``forward(image)`` maps a
camera image ``(Py, Px)`` in photons to a volume ``(Z, Vy, Vx)`` in photons per voxel on the
projector's grid. The projector is not a parameter: a checkpoint stores the weights and the
config, and is rebuilt on the same design (:mod:`lfm_studio.engine.learned.checkpoint`).
"""

from __future__ import annotations

import inspect

import torch

from lfm_studio.engine.learned.models.multiwiener import MultiWienerNet
from lfm_studio.engine.learned.models.unet import BlindUNet
from lfm_studio.engine.learned.models.unrolled_rl import UnrolledRL
from lfm_studio.engine.operators.protocol import Projector
from lfm_studio.engine.types import JSONValue

MODELS: dict[str, type[torch.nn.Module]] = {
    "unrolled-rl": UnrolledRL,
    "multiwiener": MultiWienerNet,
    "unet": BlindUNet,
}
"""Model name -> class (``lfm-studio train --model``)."""
DEFAULT_MODEL = "unrolled-rl"


def model_options(name: str) -> tuple[str, ...] | None:
    """The keyword options ``MODELS[name]`` takes after the projector (None: it takes any)."""
    parameters = list(inspect.signature(MODELS[name]).parameters.values())[1:]  # after the projector
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters):
        return None
    keyword = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    return tuple(p.name for p in parameters if p.kind in keyword)


def build_model(name: str, projector: Projector, **config: JSONValue) -> torch.nn.Module:
    """``MODELS[name](projector, **config)``, or a ValueError naming the choices (model or option)."""
    if name not in MODELS:
        raise ValueError(f"model must be one of {sorted(MODELS)}; got {name!r}. Fix: e.g. {DEFAULT_MODEL!r}.")
    options = model_options(name)
    unknown = sorted(set(config) - set(options)) if options is not None else []
    if unknown:
        raise ValueError(
            f"the {name!r} model has no option {', '.join(map(repr, unknown))}. "
            f"Fix: use its options: {', '.join(options or ())}."
        )
    return MODELS[name](projector, **config)


def model_config(model: torch.nn.Module) -> dict[str, JSONValue]:
    """The keyword config a learned model keeps as ``model.config`` (what a checkpoint stores)."""
    config = model.__dict__.get("config")
    if not isinstance(config, dict):
        raise TypeError(
            f"{type(model).__name__} has no config dict; a learned model keeps its keyword config."
        )
    return config


def parameter_count(model: torch.nn.Module) -> int:
    """Number of trainable scalars."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


__all__ = [
    "DEFAULT_MODEL",
    "MODELS",
    "BlindUNet",
    "MultiWienerNet",
    "UnrolledRL",
    "build_model",
    "model_config",
    "model_options",
    "parameter_count",
]
