"""The ``learned`` reconstruction method: a checkpoint from ``lfm-studio train`` applied to a frame.

Registered in :mod:`lfm_studio.engine.reconstruct.registry` (a provider module), so the CLI
(``lfm-studio reconstruct --method learned --model model.safetensors``), the napari plugin and
the studio offer it beside Richardson-Lucy. The checkpoint is checked against the projector
(volume and image shapes, so the depth count and field of view; the front ends that know the
PSF stack also pass its design hash and depths to :func:`~.checkpoint.load_model_for`) and loaded
once per file and projector. The frame minus the background goes in; the model's volume, in
photons per voxel, comes out.

The volume is checked before it is returned: a non-finite, all-zero or constant one is refused
(a ValueError naming the checkpoint), and one whose predicted image ``A x`` holds more than
:data:`PHOTON_BALANCE` times (or less than its inverse) the frame's photons warns
:class:`LearnedOutputWarning`: the model does not fit this data (another design, photon level
or camera than it was trained for). The predicted total costs no projection:
``sum(A x) = <x, A^T 1>``. A checkpoint written before stop 28's training floors returned volumes
of 1e29 on the README's 2048^2 light field without a word.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping
from pathlib import Path

import torch

from lfm_studio.engine.learned.checkpoint import load_model_for
from lfm_studio.engine.learned.losses import trivial_reason
from lfm_studio.engine.learned.models.common import adjoint_normaliser
from lfm_studio.engine.operators.protocol import Projector
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint
from lfm_studio.engine.reconstruct.guards import check_signal
from lfm_studio.engine.reconstruct.registry import Method, Option, register
from lfm_studio.engine.types import OptionValue

MODEL = Option(
    "model", str, None, "checkpoint written by `lfm-studio train` (.safetensors)", optional=True,
    file_filter="Checkpoints (*.safetensors)",
)  # fmt: skip
_LOADED: dict[tuple[str, int, int], tuple[torch.nn.Module, torch.Tensor]] = {}  # model, A^T 1
_KEEP = 2  # models kept loaded (a video reuses one; switching back and forth reuses two)
PHOTON_BALANCE = 10.0
"""Largest factor between the photons the volume predicts and those the frame holds, either way."""


class LearnedOutputWarning(UserWarning):
    """A learned model's volume predicts far more or fewer photons than the frame holds."""


def _model(path: str, projector: Projector) -> tuple[torch.nn.Module, torch.Tensor]:
    source = Path(path).expanduser()
    if not source.is_file():
        raise FileNotFoundError(
            f"--model {source}: no such checkpoint file. Fix: train one with `lfm-studio train`."
        )
    key = (str(source.resolve()), os.stat(source).st_mtime_ns, id(projector))
    if key not in _LOADED:
        while len(_LOADED) >= _KEEP:
            _LOADED.pop(next(iter(_LOADED)))
        _LOADED[key] = (load_model_for(source, projector)[0], adjoint_normaliser(projector))
    return _LOADED[key]


def check_learned_volume(
    volume: torch.Tensor, frame: torch.Tensor, sensitivity: torch.Tensor, path: str
) -> None:
    """Refuse a trivial ``volume`` and warn when its predicted photons ``<x, A^T 1>`` and the
    ``frame``'s (background removed) differ by more than :data:`PHOTON_BALANCE` either way."""
    reason = trivial_reason(volume)
    if reason is not None:
        raise ValueError(
            f"the learned model {path} returned a volume that is {reason}. Fix: train a model for this "
            "design and photon level (`lfm-studio train`), or use another --method."
        )
    predicted = float((volume.detach().double() * sensitivity.double()).sum())
    measured = float(frame.detach().double().sum())
    if not (measured > 0 and 1.0 / PHOTON_BALANCE <= predicted / measured <= PHOTON_BALANCE):
        warnings.warn(
            f"the learned model {path} predicts {predicted:.3g} photons on the camera where the frame "
            f"holds {measured:.3g}: the model does not fit this data. Fix: train it for this design, "
            "camera and photon level (`lfm-studio train`), or compare with --method rl.",
            LearnedOutputWarning,
            stacklevel=3,
        )


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
    model, sensitivity = _model(path, projector)
    checkpoint(cancel, progress, 0, 1, "learned model")
    check_signal(frame.detach(), torch.tensor(float(background)))  # a blank frame: RL's refusal
    signal = frame - float(background)
    with torch.set_grad_enabled(frame.requires_grad):  # differentiable when asked, no graph otherwise
        volume = model(signal)
    check_learned_volume(volume, signal, sensitivity, path)
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
