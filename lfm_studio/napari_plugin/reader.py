"""napari reader: our TIFFs (PSF stacks, light-field images, volumes) and design files.

:func:`get_reader` claims a path only when it is ours: a TIFF whose ImageJ ``Info``
property holds the lfm_studio JSON header, a JSON design file (see
:mod:`~lfm_studio.napari_plugin.design_reader`) or a JSON calibration file (its fitted lenslet
grid as a Points overlay, :mod:`~lfm_studio.napari_plugin.calibration_reader`). Any other file gets ``None``, so napari
asks its other readers. A file we claim but cannot read (e.g. a newer schema) gives an
error notification with the engine's message and no layer.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import tifffile

from lfm_studio.engine.io import read_image, read_psf_stack, read_volume
from lfm_studio.engine.io.metadata import FORMAT_NAME
from lfm_studio.napari_plugin import calibration_reader, design_reader
from lfm_studio.napari_plugin.layer_data import (
    LayerData,
    light_field_layer_data,
    psf_layer_data,
    volume_layer_data,
)
from lfm_studio.napari_plugin.notify import report_error

ReaderFunction = Callable[[Any], list[LayerData]]
TIFF_SUFFIXES = (".tif", ".tiff")
NOTHING: list[Any] = [(None,)]  # napari's "read, but no layer" sentinel


def _single_path(path: Any) -> Path | None:
    if isinstance(path, (list, tuple)):
        if len(path) != 1:
            return None
        path = path[0]
    return Path(path) if isinstance(path, (str, Path)) else None


def tiff_kind(path: Path) -> str | None:
    """The lfm_studio kind (``"psf_stack"``, ``"image"``, ``"volume"``) in a TIFF's header, or None.

    Reads the first page's ImageJ metadata only, not the pixel data.
    """
    try:
        with tifffile.TiffFile(path) as tif:
            info = (tif.imagej_metadata or {}).get("Info") if tif.is_imagej else None
    except (OSError, ValueError, tifffile.TiffFileError):
        return None
    if not isinstance(info, str) or not info.lstrip().startswith("{"):
        return None
    try:
        header = json.loads(info)
    except json.JSONDecodeError:
        return None
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        return None
    kind = header.get("kind")
    return kind if isinstance(kind, str) else None


def read_tiff(path: Any) -> list[LayerData]:
    """Layers of one of our TIFFs (napari reader function)."""
    source = _single_path(path)
    if source is None:
        return NOTHING
    kind, name = tiff_kind(source), source.stem
    try:
        if kind == "psf_stack":
            return [psf_layer_data(read_psf_stack(source), name=name, source=str(source))]
        if kind == "image":
            return [light_field_layer_data(read_image(source), name=name, source=str(source))]
        if kind == "volume":
            return [volume_layer_data(read_volume(source), name=name, source=str(source))]
        raise ValueError(
            f"{source} holds an lfm_studio {kind!r}, which this plugin does not know. Fix: update lfm_studio."
        )
    except (ValueError, OSError, TypeError) as error:
        report_error(f"lfm-studio could not open {source.name}: {error}")
        return NOTHING


def get_reader(path: Any) -> ReaderFunction | None:
    """napari ``get_reader`` hook: a reader function for our files, ``None`` for anything else."""
    source = _single_path(path)
    if source is None or not source.is_file():
        return None
    if source.suffix.lower() in TIFF_SUFFIXES:
        return read_tiff if tiff_kind(source) is not None else None
    if calibration_reader.is_calibration_file(source):
        return calibration_reader.read_calibration
    if design_reader.is_design_file(source):
        return design_reader.read_design
    return None
