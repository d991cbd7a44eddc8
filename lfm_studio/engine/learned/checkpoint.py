"""Checkpoints of learned reconstructors: safetensors weights plus a JSON header that ties them to a design.

The file is a plain safetensors file (weights only, no pickled code: safe to load from anyone)
whose metadata entry ``"lfm_studio"`` holds the header: format version, model name and config,
the design's optics hash (:func:`~lfm_studio.engine.design.hashing.optics_hash`; None for a
measured PSF), the PSF depths (m), the volume and image shapes and the voxel size (m), the
training data spec, training record (steps, seconds, seed, best validation loss) and metrics.
:func:`load_model` rebuilds the model on a projector and refuses, with a named error, a
checkpoint trained for another design or sampling. Writes are atomic; an existing file is
replaced only with ``overwrite=True``.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from safetensors import SafetensorError
from safetensors.torch import load as load_tensors
from safetensors.torch import save as save_tensors

from lfm_studio import __version__
from lfm_studio.engine.atomic_write import atomic_write
from lfm_studio.engine.learned.models import MODELS, build_model
from lfm_studio.engine.operators.protocol import Projector
from lfm_studio.engine.simulation import ImagingSetup
from lfm_studio.engine.types import JSONValue

FORMAT = "lfm_studio.learned/1"
HEADER_KEY = "lfm_studio"


@dataclass(frozen=True)
class CheckpointHeader:
    """What a checkpoint says about itself (JSON in the safetensors metadata).

    Attributes
    ----------
    model, config : model name (:data:`~lfm_studio.engine.learned.models.MODELS`) and its keyword config.
    design_hash : optics hash of the design it was trained on (None: a PSF without a design).
    depths : PSF depths in metres.
    volume_shape, image_shape : ``(Z, Vy, Vx)`` and ``(Py, Px)`` of its projector.
    voxel_size : ``(dz, dy, dx)`` in metres.
    data : the training data spec (:meth:`TrainingDataSpec.to_dict`).
    training : steps, seconds, seed, best validation loss, stop reason.
    metrics : validation/test scores.
    """

    model: str
    config: dict[str, JSONValue]
    design_hash: str | None
    depths: tuple[float, ...]
    volume_shape: tuple[int, int, int]
    image_shape: tuple[int, int]
    voxel_size: tuple[float, float, float]
    data: dict[str, JSONValue] = field(default_factory=dict)
    training: dict[str, JSONValue] = field(default_factory=dict)
    metrics: dict[str, JSONValue] = field(default_factory=dict)
    format: str = FORMAT
    version: str = __version__

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str, source: str) -> CheckpointHeader:
        try:
            raw = json.loads(text)
            if raw.get("format") != FORMAT:
                raise ValueError(f"format {raw.get('format')!r}, expected {FORMAT!r}")
            return cls(**{**raw, "depths": tuple(raw["depths"]), "volume_shape": tuple(raw["volume_shape"]),
                          "image_shape": tuple(raw["image_shape"]), "voxel_size": tuple(raw["voxel_size"])})  # fmt: skip
        except (ValueError, TypeError, KeyError) as error:
            raise ValueError(
                f"checkpoint {source} has no readable lfm_studio header ({error}). Fix: use a file written by "
                "`lfm-studio train`."
            ) from error


def header_for(model_name: str, config: Mapping[str, JSONValue], setup: ImagingSetup, design_hash: str | None,
               depths: tuple[float, ...], *, data: dict[str, JSONValue] | None = None,
               training: dict[str, JSONValue] | None = None,
               metrics: dict[str, JSONValue] | None = None) -> CheckpointHeader:  # fmt: skip
    """The header of a model trained on ``setup`` (an ImagingSetup) for a design/PSF."""
    return CheckpointHeader(
        model=model_name, config=dict(config), design_hash=design_hash, depths=tuple(float(z) for z in depths),
        volume_shape=tuple(int(n) for n in setup.volume_shape),  # type: ignore[arg-type]
        image_shape=tuple(int(n) for n in setup.projector.image_shape),  # type: ignore[arg-type]
        voxel_size=tuple(float(v) for v in setup.voxel_size),  # type: ignore[arg-type]
        data=data or {}, training=training or {}, metrics=metrics or {},
    )  # fmt: skip


def save_checkpoint(
    path: str | os.PathLike, model: torch.nn.Module, header: CheckpointHeader, *, overwrite: bool = False
) -> Path:
    """Write ``model``'s weights and ``header`` atomically to ``path``."""
    tensors = {name: value.detach().cpu().contiguous() for name, value in model.state_dict().items()}
    payload = save_tensors(tensors, metadata={HEADER_KEY: header.to_json()})
    return atomic_write(path, lambda fh: fh.write(payload), overwrite=overwrite)


def read_checkpoint(path: str | os.PathLike) -> tuple[CheckpointHeader, dict[str, torch.Tensor]]:
    """The header and weights of a checkpoint file (named errors for a missing or foreign file)."""
    source = Path(path).expanduser()
    if not source.is_file():
        raise FileNotFoundError(
            f"--model {source}: no such checkpoint file. Fix: train one with `lfm-studio train`."
        )
    data = source.read_bytes()
    try:
        tensors = load_tensors(data)
        metadata = _metadata(data)
    except (SafetensorError, ValueError, json.JSONDecodeError) as error:
        raise ValueError(f"checkpoint {source} is not a safetensors file ({error}).") from error
    if HEADER_KEY not in metadata:
        raise ValueError(
            f"checkpoint {source} has no lfm_studio header. Fix: use a file written by `lfm-studio train`."
        )
    return CheckpointHeader.from_json(metadata[HEADER_KEY], str(source)), tensors


def _metadata(data: bytes) -> dict[str, str]:
    """The ``__metadata__`` of a safetensors byte string (its 8-byte length + JSON header)."""
    length = int.from_bytes(data[:8], "little")
    return json.loads(data[8 : 8 + length]).get("__metadata__", {}) or {}


def check_matches(
    header: CheckpointHeader,
    projector: Projector,
    source: str,
    *,
    voxel_size: tuple[float, float, float] | None = None,
    design_hash: str | None = None,
    depths: tuple[float, ...] | None = None,
) -> None:
    """Refuse a checkpoint trained for another design or sampling than ``projector`` (and, where the
    caller knows them, the voxel size in m, the design's optics hash and the PSF depths in m)."""
    if header.design_hash is not None and design_hash is not None and header.design_hash != design_hash:
        raise ValueError(
            f"checkpoint {source} was trained for another design (optics hash {header.design_hash[:12]}..., "
            f"this design {design_hash[:12]}...). Fix: train a model for this design (`lfm-studio train`)."
        )
    mine = {"volume_shape": tuple(int(n) for n in projector.volume_shape),
            "image_shape": tuple(int(n) for n in projector.image_shape)}  # fmt: skip
    for name, value in mine.items():
        if value != getattr(header, name):
            raise ValueError(
                f"checkpoint {source} was trained for {name} {getattr(header, name)}, this setup has "
                f"{value}. Fix: use the same design, depths and field of view as in training."
            )
    if voxel_size is not None and not all(
        math.isclose(a, b, rel_tol=1e-6) for a, b in zip(voxel_size, header.voxel_size, strict=True)
    ):
        raise ValueError(
            f"checkpoint {source} was trained for voxel size {header.voxel_size} m, this setup has "
            f"{tuple(voxel_size)} m. Fix: use the same design and sampling as in training."
        )
    if depths is not None and (
        len(depths) != len(header.depths)
        or not all(
            math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-12)
            for a, b in zip(depths, header.depths, strict=True)
        )
    ):
        raise ValueError(
            f"checkpoint {source} was trained for depths {header.depths} m, this PSF has {tuple(depths)} m. "
            "Fix: simulate the PSF at the training depths."
        )


def check_architecture(header: CheckpointHeader, source: str, projector: Projector | None = None) -> None:
    """Refuse a checkpoint whose model was written with another architecture of its class.

    A model class may declare ``ARCHITECTURE`` (an integer, 1 when absent) and record it as
    ``config["architecture"]``; a checkpoint without the entry is architecture 1. A class with a
    ``builds(architecture, projector)`` classmethod says itself which older ones it still builds
    on ``projector``.
    """
    model_class = MODELS.get(header.model)
    current = getattr(model_class, "ARCHITECTURE", 1)
    found = header.config.get("architecture", 1)
    builds = getattr(model_class, "builds", None)
    accepted = builds(found, projector) if builds is not None and projector is not None else found == current
    if not accepted:
        raise ValueError(
            f"checkpoint {source} holds a {header.model!r} model of architecture {found!r} (written by lfm_studio "
            f"{header.version}); this version builds architecture {current}. Fix: train it again "
            f"(`lfm-studio train --model {header.model}`)."
        )


def load_model(
    path: str | os.PathLike,
    setup: ImagingSetup,
    *,
    design_hash: str | None = None,
    depths: tuple[float, ...] | None = None,
) -> tuple[torch.nn.Module, CheckpointHeader]:
    """The model of checkpoint ``path`` rebuilt on ``setup``'s projector (an ImagingSetup), in eval mode."""
    return load_model_for(path, setup.projector, voxel_size=setup.voxel_size, design_hash=design_hash,
                          depths=depths)  # fmt: skip


def load_model_for(
    path: str | os.PathLike,
    projector: Projector,
    *,
    voxel_size: tuple[float, float, float] | None = None,
    design_hash: str | None = None,
    depths: tuple[float, ...] | None = None,
) -> tuple[torch.nn.Module, CheckpointHeader]:
    """The model of checkpoint ``path`` rebuilt on ``projector``, in eval mode (checks as :func:`check_matches`)."""
    header, tensors = read_checkpoint(path)
    check_matches(header, projector, str(path), voxel_size=voxel_size, design_hash=design_hash, depths=depths)
    check_architecture(header, str(path), projector)
    model = build_model(header.model, projector, **header.config)
    dtype = next(iter(model.parameters())).dtype
    model.load_state_dict({k: v.to(dtype) if v.is_floating_point() else v for k, v in tensors.items()})
    return model.eval(), header
