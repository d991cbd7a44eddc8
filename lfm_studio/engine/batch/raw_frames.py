"""Raw camera frames in a video run: each frame corrected and rectified with a calibration.

A recording from a real microscope holds raw frames: ADU with the camera's dark level, its
defective pixels and vignetting, and (conventional LFM) a lenslet grid that is off the pixel
lattice. :func:`~lfm_studio.engine.batch.reconstruct_video` given ``calibration=`` (a file from
``lfm-studio calibrate``) rectifies every frame as the single-frame path does
(:func:`~lfm_studio.engine.calibration.rectify_frame`), then converts the dark-subtracted ADU to
photons with a baseline of 0 (:func:`~lfm_studio.engine.calibration.raw_camera.dark_subtracted_camera`).

The task graph carries a small :class:`RawFrameSpec` (the file's path, the lenslet block and the
SHA-256 of the file), never the calibration: each worker loads it once and keeps its prepared
corrections (:func:`cached_rectifier`), as it keeps its projector.
"""

from __future__ import annotations

import hashlib
import os
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from lfm_studio.engine.calibration import FrameRectifier, frame_rectifier, load_calibration
from lfm_studio.engine.types import JSONValue


@dataclass(frozen=True)
class RawFrameSpec:
    """How to rectify a video's raw frames: the calibration file ``path``, the ``lenslets``
    ``(ny, nx)`` block asked for (None: the calibration's lit block), the file's ``sha256`` (a
    resume with another calibration is refused; a worker refuses a file changed under it) and the
    ``block`` ``(i0, ni, j0, nj)`` the rectifier uses (None: Fourier LFM, corrected only)."""

    path: str
    sha256: str
    lenslets: tuple[int, int] | None = None
    block: tuple[int, int, int, int] | None = None

    def describe(self) -> dict[str, JSONValue]:
        """JSON-ready record for the run's metadata and resume check: the EFFECTIVE lenslet block
        (an explicit ``lenslets`` equal to the calibration's block records the same as none)."""
        block: JSONValue = None if self.block is None else [int(v) for v in self.block]
        lenslets: JSONValue = None if self.block is None else [int(self.block[1]), int(self.block[3])]
        return {"path": self.path, "sha256": self.sha256, "lenslets": lenslets, "block": block}

    def legacy_describe(self) -> dict[str, JSONValue]:
        """The record of stores written before the effective block was kept: the ``lenslets``
        asked for (None for the calibration's block) and no ``block``; such a store still resumes."""
        lenslets: JSONValue = None if self.lenslets is None else [int(v) for v in self.lenslets]
        return {"path": self.path, "sha256": self.sha256, "lenslets": lenslets}


CACHE_SIZE = 2  # calibrations kept per process (one run needs one)
_CACHE: OrderedDict[RawFrameSpec, FrameRectifier] = OrderedDict()


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def raw_frame_spec(
    calibration: str | os.PathLike[str], lenslets: tuple[int, int] | None = None
) -> tuple[RawFrameSpec, FrameRectifier]:
    """The spec of calibration file ``calibration`` and its rectifier, loaded here once so that a
    bad file or lenslet block is refused before any work (a ``ValueError`` naming the file)."""
    path = Path(calibration).expanduser().resolve()
    if not path.is_file():
        raise FileNotFoundError(
            f"calibration {path}: no such file. Fix: give the .json written by `lfm-studio calibrate`."
        )
    block = None if lenslets is None else (int(lenslets[0]), int(lenslets[1]))
    digest = _digest(path)
    try:
        rectifier = frame_rectifier(load_calibration(path), lenslets=block)
    except ValueError as error:
        raise ValueError(f"calibration {path}: {error}") from error
    spec = RawFrameSpec(str(path), digest, block, rectifier.block)
    _remember(spec, rectifier)
    return spec, rectifier


def _remember(spec: RawFrameSpec, rectifier: FrameRectifier) -> None:
    _CACHE[spec] = rectifier
    _CACHE.move_to_end(spec)
    while len(_CACHE) > CACHE_SIZE:
        _CACHE.popitem(last=False)


def cached_rectifier(spec: RawFrameSpec) -> FrameRectifier:
    """The rectifier of ``spec``, loaded once per process; a file whose content changed since the
    run started is refused (its frames would be corrected with another calibration)."""
    if spec in _CACHE:
        _CACHE.move_to_end(spec)
        return _CACHE[spec]
    path = Path(spec.path)
    if not path.is_file() or _digest(path) != spec.sha256:
        raise ValueError(
            f"calibration {spec.path} changed or vanished since this run started (SHA-256 differs). "
            "Fix: restore it, or start a new run (overwrite) with the new calibration."
        )
    rectifier = frame_rectifier(load_calibration(path), lenslets=spec.lenslets)
    _remember(spec, rectifier)
    return rectifier


def rectified_frame(spec: RawFrameSpec, frame: object, dtype: torch.dtype) -> torch.Tensor:
    """Raw ``frame`` (Y, X, ADU) corrected and rectified with ``spec``'s calibration, in ``dtype``:
    ADU above the dark level per rectified pixel."""
    pixels = torch.from_numpy(np.asarray(frame, dtype=np.float64))
    return cached_rectifier(spec)(pixels).to(dtype)
