"""The ``learned`` reconstruction method: a checkpoint from ``lfm-studio train`` applied to a frame.

Registered in :mod:`lfm_studio.engine.reconstruct.registry` (a provider module), so the CLI
(``lfm-studio reconstruct --method learned --model model.safetensors``), the napari plugin and
the studio offer it beside Richardson-Lucy. The checkpoint is checked against the projector
(volume and image shapes, so the depth count and field of view; the front ends that know the
PSF stack also pass its design hash and depths to :func:`~.checkpoint.load_model_for`) and loaded
once per file and projector. The frame minus the background goes in; the model's volume, in
photons per voxel, comes out.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

import torch

from lfm_studio.engine.learned.checkpoint import load_model_for
from lfm_studio.engine.operators.protocol import Projector
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint
from lfm_studio.engine.reconstruct.registry import Method, Option, register
from lfm_studio.engine.types import OptionValue

MODEL = Option(
    "model", str, None, "checkpoint written by `lfm-studio train` (.safetensors)", optional=True,
    file_filter="Checkpoints (*.safetensors)",
)  # fmt: skip
_LOADED: dict[tuple[str, int, int], torch.nn.Module] = {}
_KEEP = 2  # models kept loaded (a video reuses one; switching back and forth reuses two)


def _model(path: str, projector: Projector) -> torch.nn.Module:
    source = Path(path).expanduser()
    if not source.is_file():
        raise FileNotFoundError(
            f"--model {source}: no such checkpoint file. Fix: train one with `lfm-studio train`."
        )
    key = (str(source.resolve()), os.stat(source).st_mtime_ns, id(projector))
    if key not in _LOADED:
        while len(_LOADED) >= _KEEP:
            _LOADED.pop(next(iter(_LOADED)))
        _LOADED[key] = load_model_for(source, projector)[0]
    return _LOADED[key]


def run_learned(
    projector: Projector,
    frame: torch.Tensor,
    options: Mapping[str, OptionValue],
    progress: ProgressCallback | None,
    cancel: CancelToken,
) -> torch.Tensor:
    """The volume of checkpoint ``options["model"]`` for ``frame`` (photons, baseline removed)."""
    path = options.get("model")
    if not isinstance(path, str) or not path:
        raise ValueError(
            "method 'learned' needs a checkpoint: --model model.safetensors. Fix: train one with "
            "`lfm-studio train DESIGN --out model.safetensors`."
        )
    background = options.get("background", 0.0)
    if isinstance(background, bool) or not isinstance(background, (int, float)):
        raise ValueError(f"background must be a number; got {background!r}.")
    model = _model(path, projector)
    checkpoint(cancel, progress, 0, 1, "learned model")
    with torch.set_grad_enabled(frame.requires_grad):  # differentiable when asked, no graph otherwise
        volume = model(frame - float(background))
    checkpoint(cancel, progress, 1, 1, "learned model")
    return volume


LEARNED = register(
    Method(
        "learned",
        "Learned model",
        "a reconstructor trained from the design with `lfm-studio train` (unrolled RL, MultiWienerNet, U-Net)",
        (MODEL,),
        run_learned,
        differentiable=True,
    ),
    overwrite=True,
)
