"""Read and write volumes and camera images as ImageJ-hyperstack TIFFs (PSF stacks: :mod:`.psf_tiff`).

Files open in Fiji and napari with their physical scale (ImageJ ``unit=um``,
``spacing`` and X/YResolution) and carry our full header as JSON in the ImageJ
``Info`` property (see :mod:`lfm_studio.engine.io.metadata`): exact depth list,
pixel size, magnification, wavelength, the design and free metadata.

Data is stored as float32 (float64 and other real types are converted; uint8 and
uint16 are kept; complex is refused) and read back as ``dtype`` (float32 by
default). Writes are atomic and never replace a file unless ``overwrite=True``.
TIFFs from other tools are read too; what they lack is passed as keywords, which
also override what a file says.

What the ImageJ calibration means: for a volume, the voxel size; for an image,
its pixel pitch; for a PSF stack, the *sample-side* pixel size
``pixel_size / magnification``, so x, y and the depth axis share one space.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from lfm_studio.engine.errors import listed
from lfm_studio.engine.io import hyperstack as hs
from lfm_studio.engine.io.containers import LightFieldImage, Volume, voxel_triple
from lfm_studio.engine.io.metadata import MissingMetadataError, decode_header, encode_header, require_kind
from lfm_studio.engine.io.psf_tiff import read_psf_stack, write_psf_stack

_VOLUME_UNITS = {"depths_um": "um", "voxel_size_um": "um"}
_IMAGE_UNITS = {"pixel_size_um": "um"}

MAX_SAMPLE_SIZE = 1e-3
"""Largest voxel or pixel size (m) the writers take: a microscope samples in um, so 1 mm or more
is almost surely micrometres passed as metres (a "0.7" voxel is 0.7 m)."""


def _require_microscope_sizes(name: str, sizes: Sequence[float]) -> None:
    """Refuse sizes (metres) of :data:`MAX_SAMPLE_SIZE` or more, naming ``name`` and the um reading."""
    if max(sizes) < MAX_SAMPLE_SIZE:
        return
    fix = (
        f"did you pass um? Use {name}=({listed(sizes, unit=' * um')})"
        if max(sizes) >= 0.1
        else f"give {name} in metres, e.g. 2 * um"
    )
    raise ValueError(
        f"{name} must be in metres, below {MAX_SAMPLE_SIZE * 1e3:g} mm; got ({listed(sizes)}) m, and a "
        f"{max(sizes):g} m sample is no microscope's. Nothing was written. Fix: {fix} with um from "
        "lfm_studio.engine.units."
    )


def write_volume(
    path: str | os.PathLike,
    volume: Volume | torch.Tensor,
    *,
    voxel_size: Sequence[float] | None = None,
    depths: Sequence[float] | None = None,
    metadata: dict[str, Any] | None = None,
    overwrite: bool = False,
) -> Path:
    """Save a volume ``(Z, Y, X)`` or ``(T, Z, Y, X)`` as an ImageJ hyperstack; return the path.

    ``volume`` is a :class:`Volume` or a tensor; ``voxel_size`` ``(dz, dy, dx)`` in metres is
    required for a tensor, and ``voxel_size``/``depths``/``metadata`` replace a Volume's own.
    Refused before writing: a voxel of 1 mm or more (micrometres passed as metres), an empty
    volume, a name not ending in ``.tif``/``.tiff``.
    """
    if isinstance(volume, Volume):
        volume = Volume(
            volume.data,
            volume.voxel_size if voxel_size is None else voxel_triple(voxel_size),
            volume.depths if depths is None else tuple(depths),
            volume.metadata if metadata is None else metadata,
        )
    else:
        if voxel_size is None:
            raise TypeError(
                "write_volume needs voxel_size=(dz, dy, dx) in metres for a tensor, e.g. (2*um,)*3."
            )
        volume = Volume(
            torch.as_tensor(volume),
            voxel_triple(voxel_size),
            None if depths is None else tuple(depths),
            metadata or {},
        )
    _require_microscope_sizes("voxel_size", volume.voxel_size)
    array, source = hs.tiff_array("volume", volume.data)
    dz, dy, dx = volume.voxel_size
    axes = "TZYX" if array.ndim == 4 else "ZYX"
    fields = {
        "shape": list(array.shape),
        "axes": axes,
        "source_dtype": source,
        "voxel_size_um": list(volume.voxel_size),
        "depths_um": list(volume.depths) if volume.depths is not None else None,
        "metadata": volume.metadata,
    }
    frames = array.shape[0] if array.ndim == 4 else 1
    return hs.write_hyperstack(
        path,
        array,
        axes=axes,
        pixel_size=(dy, dx),
        z_spacing=dz,
        labels=hs.depth_labels(volume.depths, frames) if volume.depths is not None else None,
        info=encode_header("volume", fields, _VOLUME_UNITS),
        overwrite=overwrite,
    )


def read_volume(
    path: str | os.PathLike,
    *,
    voxel_size: Sequence[float | None] | None = None,
    depths: Sequence[float] | None = None,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> Volume:
    """Load a :class:`Volume` from our TIFFs or another tool's (ImageJ, OME or plain).

    ``voxel_size`` ``(dz, dy, dx)`` in metres overrides the file; an entry may be
    ``None`` to keep the file's value, e.g. ``(2 * um, None, None)``. ``depths``
    (metres, one per slice) overrides the file's depth list.
    """
    name = str(path)
    raw = hs.read_hyperstack(path)
    header = decode_header(raw.info, name, _VOLUME_UNITS)
    if header is not None:
        require_kind(header, "volume", name)
        array = hs.reshape_to_header(raw.array, header["shape"], name)
        stored = list(header["voxel_size_um"])
        stored_depths, metadata = header.get("depths_um"), header.get("metadata") or {}
    else:
        array = hs.as_stack(raw, name, min_ndim=3, max_ndim=4, what="volume")
        stored = [raw.calibration.dz, raw.calibration.dy, raw.calibration.dx]
        stored_depths, metadata = None, {}
    if voxel_size is not None:
        if len(voxel_size) != 3:
            raise ValueError(f"voxel_size must be (dz, dy, dx) in metres; got {voxel_size!r}.")
        stored = [s if v is None else v for s, v in zip(stored, voxel_size, strict=True)]
    missing = [f"d{axis}" for axis, value in zip("zyx", stored, strict=True) if value is None]
    if missing:
        hint = (
            "Pass voxel_size=(dz, dy, dx) in metres to read_volume, e.g. voxel_size=(2 * um, 0.5 * um, 0.5 * um); "
            "an entry may be None to keep the file's value."
        )
        raise MissingMetadataError(name, ["voxel_size"], hint, what=f"voxel size {', '.join(missing)}")
    return Volume(
        data=hs.to_tensor(array, dtype, device, name=name),
        voxel_size=voxel_triple(stored),
        depths=tuple(depths) if depths is not None else stored_depths,
        metadata=metadata,
    )


def write_image(
    path: str | os.PathLike,
    image: LightFieldImage | torch.Tensor,
    *,
    pixel_size: float | None = None,
    metadata: dict[str, Any] | None = None,
    overwrite: bool = False,
) -> Path:
    """Save a camera image ``(Y, X)`` or frames ``(T, Y, X)`` as an ImageJ TIFF; return the path.

    ``pixel_size`` (metres, below 1 mm) is required for a tensor and replaces a LightFieldImage's own.
    """
    if isinstance(image, LightFieldImage):
        image = LightFieldImage(
            image.data,
            image.pixel_size if pixel_size is None else pixel_size,
            image.metadata if metadata is None else metadata,
        )
    else:
        if pixel_size is None:
            raise TypeError("write_image needs pixel_size in metres for a tensor, e.g. pixel_size=6.5 * um.")
        image = LightFieldImage(torch.as_tensor(image), pixel_size, metadata or {})
    _require_microscope_sizes("pixel_size", (image.pixel_size,))
    array, source = hs.tiff_array("image", image.data)
    axes = "TYX" if array.ndim == 3 else "YX"
    fields = {
        "shape": list(array.shape),
        "axes": axes,
        "source_dtype": source,
        "pixel_size_um": image.pixel_size,
        "metadata": image.metadata,
    }
    return hs.write_hyperstack(
        path,
        array,
        axes=axes,
        pixel_size=(image.pixel_size, image.pixel_size),
        z_spacing=None,
        labels=None,
        info=encode_header("image", fields, _IMAGE_UNITS),
        overwrite=overwrite,
    )


def read_image(
    path: str | os.PathLike,
    *,
    pixel_size: float | None = None,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> LightFieldImage:
    """Load a :class:`LightFieldImage` (``(Y, X)`` or ``(T, Y, X)``); ``pixel_size`` (m) overrides the file."""
    name = str(path)
    raw = hs.read_hyperstack(path)
    header = decode_header(raw.info, name, _IMAGE_UNITS)
    if header is not None:
        require_kind(header, "image", name)
        array = hs.reshape_to_header(raw.array, header["shape"], name)
        stored, metadata = header.get("pixel_size_um"), header.get("metadata") or {}
    else:
        array = hs.as_stack(raw, name, min_ndim=2, max_ndim=3, what="image")
        metadata = {}
        stored = (
            None if pixel_size is not None else hs.square_pixel(raw.calibration.dy, raw.calibration.dx, name)
        )
    value = pixel_size if pixel_size is not None else stored
    if value is None:
        raise MissingMetadataError(
            name, ["pixel_size"], "Pass pixel_size to read_image, e.g. pixel_size=6.5 * um (metres)."
        )
    return LightFieldImage(
        data=hs.to_tensor(array, dtype, device, name=name), pixel_size=float(value), metadata=metadata
    )


__all__ = ["read_image", "read_psf_stack", "read_volume", "write_image", "write_psf_stack", "write_volume"]
