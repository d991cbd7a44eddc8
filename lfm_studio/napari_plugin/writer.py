"""napari writer: an image layer back to our TIFF, with its sampling and metadata.

Layers made by this plugin are written as what they are (PSF stack, light-field
image, volume) from their recorded metadata, so a read-write-read round trip keeps
depths, pixel size, magnification, wavelength and design exactly. Other image layers
are written from their napari scale, read as micrometres: a 2-D layer as a camera
image (square pixels), a 3-D or 4-D layer as a volume ``(Z, Y, X)`` / ``(T, Z, Y, X)``.
Writes are atomic (a failed write leaves no partial file). napari's *Save Layers*
dialog asks before replacing an existing file and then calls the writer, which cannot tell
that confirmed call from a script's ``napari.save_layers``: it replaces what it is given in
both cases (docs/napari_plugin.md says so; scripts check first or use the engine's writers,
which refuse an existing file unless ``overwrite=True``).
"""

from __future__ import annotations

import math
from typing import Any

from lfm_studio.engine.io import write_image, write_psf_stack, write_volume
from lfm_studio.napari_plugin.layer_data import (
    LayerError,
    image_from_layer,
    kind_of,
    light_field_layer_data,
    psf_layer_data,
    stack_from_layer,
    volume_from_layer,
    volume_layer_data,
)
from lfm_studio.napari_plugin.notify import report_error, report_warning


def _check_scale(name: str, scale: Any, expected: tuple[float, ...]) -> None:
    """Warn when the layer's napari scale no longer matches the sampling its metadata records."""
    if scale is None:
        return
    shown = tuple(float(s) for s in scale)
    if len(shown) == len(expected) and all(
        math.isclose(a, b, rel_tol=1e-6) for a, b in zip(shown, expected, strict=True)
    ):
        return
    report_warning(
        f"Layer {name!r} has scale {shown} um but its lfm_studio metadata records {tuple(expected)} um; the file "
        "keeps the recorded sampling. Fix: to change the sampling, edit the metadata, not the layer scale."
    )


def _write(path: str, data: Any, meta: dict[str, Any]) -> str:
    metadata = meta.get("metadata") or {}
    name, scale = str(meta.get("name", "layer")), meta.get("scale")
    if meta.get("rgb"):
        raise LayerError(
            f"layer {name!r} is RGB; our TIFFs hold one grayscale channel. Fix: split the channels."
        )
    kind = kind_of(metadata)
    ndim = len(getattr(data, "shape", ()))
    if kind == "psf_stack":
        stack = stack_from_layer(data, metadata, name=name)
        _check_scale(name, scale, psf_layer_data(stack, name=name)[1]["scale"])
        return str(write_psf_stack(path, stack, overwrite=True))
    if kind == "light_field" or (kind is None and ndim == 2):
        image = image_from_layer(data, metadata, scale, name=name)
        _check_scale(name, scale, light_field_layer_data(image, name=name)[1]["scale"])
        return str(write_image(path, image, overwrite=True))
    if kind == "volume" or (kind is None and ndim in (3, 4)):
        volume = volume_from_layer(data, metadata, scale, name=name)
        _check_scale(name, scale, volume_layer_data(volume, name=name)[1]["scale"])
        return str(write_volume(path, volume, overwrite=True))
    raise LayerError(
        f"layer {name!r} has {ndim} dimensions; lfm_studio TIFFs hold images (Y, X), volumes (Z, Y, X) or "
        "(T, Z, Y, X) and PSF stacks. Fix: save it with napari's built-in writer."
    )


def write_image_layer(path: str, data: Any, meta: dict[str, Any]) -> list[str]:
    """napari single-layer writer hook: the paths written (empty, with an error notification, on failure)."""
    try:
        return [_write(path, data, meta)]
    except (ValueError, TypeError, OSError) as error:
        report_error(f"lfm-studio could not save layer {meta.get('name', '')!r} to {path}: {error}")
        return []
