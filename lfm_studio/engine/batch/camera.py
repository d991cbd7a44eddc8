"""The camera conversion of a video's frames (counts -> photons), shared by the CLI and the studio.

:func:`video_camera` reads the lfm_studio camera metadata from a TIFF video's header (never its
pixels beyond the first frame) and resolves the conversion as
:func:`~lfm_studio.engine.io.resolve_calibration` does for one image: values given by the user
win, then the file's metadata, then ``fallback`` (the studio passes its design's camera),
else the baseline is estimated from the first frame and the gain taken as 1, each with a note.
"""

from __future__ import annotations

from pathlib import Path

import tifffile
import torch

from lfm_studio.engine.batch.frames import TIFF_SUFFIXES, FrameSource
from lfm_studio.engine.io import CameraCalibration, resolve_calibration
from lfm_studio.engine.io.camera_counts import calibration_from_metadata
from lfm_studio.engine.io.metadata import decode_header


def tiff_metadata(path: str | Path) -> dict[str, object]:
    """The lfm_studio metadata in a TIFF's ImageJ header (camera calibration), read without the pixels;
    ``{}`` for anything else (a folder, a Zarr array, a TIFF without it)."""
    path = Path(path)
    if not (path.is_file() and path.suffix.lower() in TIFF_SUFFIXES):
        return {}
    with tifffile.TiffFile(path) as tif:
        info = (tif.imagej_metadata or {}).get("Info") if tif.is_imagej else None
    header = decode_header(info if isinstance(info, str) else None, str(path), {})
    metadata = header.get("metadata") if header is not None else None
    return metadata if isinstance(metadata, dict) else {}


def video_camera(
    source: FrameSource,
    *,
    baseline: float | None = None,
    gain: float | None = None,
    read_noise: float | None = None,
    quantum_efficiency: float | None = None,
    fallback: CameraCalibration | None = None,
) -> tuple[CameraCalibration, list[str]]:
    """The camera calibration of ``source``'s frames and the notes on what was assumed.

    ``baseline``/``gain``/``read_noise``/``quantum_efficiency`` (ADU, ADU per electron,
    electrons rms, photo-electrons per photon) win over the file's metadata; without them and
    without metadata, ``fallback`` is used when given (noted), else the baseline is estimated
    from the first frame (:func:`resolve_calibration`).
    """
    metadata = tiff_metadata(source.path)
    given = any(value is not None for value in (baseline, gain, read_noise, quantum_efficiency))
    if fallback is not None and not given and calibration_from_metadata(metadata) is None:
        note = f"{Path(source.path).name} carries no camera metadata; converted with {fallback.source}."
        return fallback, [note]
    first = torch.from_numpy(source.read(0, 1)[0].astype("float64"))
    return resolve_calibration(
        metadata,
        first,
        baseline=baseline,
        gain=gain,
        read_noise=read_noise,
        quantum_efficiency=quantum_efficiency,
    )
