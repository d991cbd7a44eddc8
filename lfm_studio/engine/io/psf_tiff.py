"""Read and write a :class:`PSFStack` as an ImageJ-hyperstack TIFF (see :mod:`.tiff_io`).

The ImageJ calibration of a PSF stack is the *sample-side* pixel size
``pixel_size / magnification``, so x, y and the depth axis share one space in Fiji
and napari; the header keeps the sensor pitch and magnification exactly.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path

import torch

from lfm_studio.engine.io import hyperstack as hs
from lfm_studio.engine.io.metadata import (
    MissingMetadataError,
    decode_header,
    design_from_header,
    design_kind,
    design_to_json,
    encode_header,
    layout_metadata,
    require_kind,
    split_layout_metadata,
)
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.units import um

_PSF_UNITS = {"depths_um": "um", "pixel_size_um": "um", "object_pixel_size_um": "um", "wavelength_nm": "nm"}


def write_psf_stack(path: str | os.PathLike, stack: PSFStack, *, overwrite: bool = False) -> Path:
    """Save a :class:`PSFStack` as an ImageJ hyperstack TIFF; return the path written.

    Shape ``(Z, Y, X)`` is stored with ImageJ axes ``ZYX``; leading batch dims
    ``(..., Z, Y, X)`` are flattened into ImageJ frames (``TZYX``) and restored on
    reading. The ImageJ z spacing is the mean depth step (the exact, possibly
    non-uniform, depths are in the header and in the slice labels).
    """
    if not isinstance(stack, PSFStack):
        raise TypeError(f"write_psf_stack expects a PSFStack; got {type(stack).__name__}.")
    array, source = hs.tiff_array("PSFStack.data", stack.data)
    *lead, nz, ny, nx = array.shape
    frames = math.prod(lead)
    array = array.reshape(frames, nz, ny, nx) if lead else array
    fields = {
        "shape": list(stack.data.shape),
        "axes": "ZYX" if not lead else "B" * len(lead) + "ZYX",
        "source_dtype": source,
        "depths_um": list(stack.depths),
        "pixel_size_um": stack.pixel_size,
        "magnification": float(stack.magnification),
        "object_pixel_size_um": stack.object_pixel_size,
        "wavelength_nm": stack.wavelength,
        "design": design_to_json(stack.design),
        "design_kind": design_kind(stack.design),
        "metadata": {**stack.metadata, **layout_metadata(stack.patterns, stack.volume_oversampling)},
    }
    return hs.write_hyperstack(
        path,
        array,
        axes="TZYX" if lead else "ZYX",
        pixel_size=(stack.object_pixel_size, stack.object_pixel_size),
        z_spacing=hs.mean_step(stack.depths),
        labels=hs.depth_labels(stack.depths, frames),
        info=encode_header("psf_stack", fields, _PSF_UNITS),
        overwrite=overwrite,
    )


def read_psf_stack(
    path: str | os.PathLike,
    *,
    pixel_size: float | None = None,
    magnification: float | None = None,
    wavelength: float | None = None,
    depths: Sequence[float] | None = None,
    rebuild_design: bool = True,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> PSFStack:
    """Load a PSF stack written by :func:`write_psf_stack` or by another tool (e.g. beads).

    Parameters
    ----------
    path : TIFF file.
    pixel_size : sensor pixel pitch in metres (overrides the file).
    magnification : sample-to-sensor lateral magnification (overrides the file).
    wavelength : emission wavelength in metres (overrides the file).
    depths : depth of each slice in metres (overrides the file).
    rebuild_design : turn the embedded design JSON back into a Design when
        ``lfm_studio.engine.design.design_from_json`` exists; otherwise, or when
        False, ``stack.design`` is the JSON dict.
    dtype, device : of the returned data.

    For a foreign file, the ImageJ/OME calibration is taken as the sample-side pixel
    size, so ``pixel_size = calibration * magnification``; give whichever is missing.

    Raises
    ------
    MissingMetadataError
        The file lacks a value and no keyword gives it; the message says which.
    """
    name = str(path)
    raw = hs.read_hyperstack(path)
    header = decode_header(raw.info, name, _PSF_UNITS)
    if header is not None:
        require_kind(header, "psf_stack", name)
        array = hs.reshape_to_header(raw.array, header["shape"], name)
        stored = {
            "pixel_size": header.get("pixel_size_um"),
            "magnification": header.get("magnification"),
            "wavelength": header.get("wavelength_nm"),
            "depths": header.get("depths_um"),
        }
        design = design_from_header(
            header.get("design"), kind=header.get("design_kind"), rebuild=rebuild_design, path=name
        )
        layout, metadata = split_layout_metadata(header.get("metadata"), where=name)
        object_px = header.get("object_pixel_size_um")
    else:
        array = hs.as_stack(raw, name, min_ndim=3, max_ndim=4, what="PSF stack")
        stored = {"pixel_size": None, "magnification": None, "wavelength": None, "depths": None}
        design, metadata, layout = None, {}, {}
        given = pixel_size is not None and magnification is not None
        object_px = None if given else hs.square_pixel(raw.calibration.dy, raw.calibration.dx, name)
    px = pixel_size if pixel_size is not None else stored["pixel_size"]
    mag = magnification if magnification is not None else stored["magnification"]
    if object_px is not None:
        if px is None and mag is not None:
            px = object_px * mag
        elif mag is None and px is not None:
            mag = px / object_px
    wl = wavelength if wavelength is not None else stored["wavelength"]
    zs = depths if depths is not None else stored["depths"]
    values = {"pixel_size": px, "magnification": mag, "wavelength": wl, "depths": zs}
    missing = [key for key, value in values.items() if value is None]
    if px is None and mag is None and object_px is not None:
        missing.remove("pixel_size")
    if missing:
        examples = {
            "pixel_size": "pixel_size=6.5 * um (sensor pixel pitch, metres)",
            "magnification": "magnification=20.0"
            + (f" (the file's {object_px / um:.6g} um pixels are taken as sample-side)" if object_px else ""),
            "wavelength": "wavelength=525 * nm (metres)",
            "depths": f"depths=[...] ({array.shape[-3]} depths in metres, one per slice)",
        }
        hint = "Pass them to read_psf_stack, e.g. " + ", ".join(examples[key] for key in missing) + "."
        raise MissingMetadataError(name, missing, hint)
    assert px is not None and mag is not None and wl is not None and zs is not None  # else `missing`
    return PSFStack(
        data=hs.to_tensor(array, dtype, device, name=name),
        depths=tuple(zs),
        pixel_size=float(px),
        magnification=float(mag),
        wavelength=float(wl),
        design=design,
        metadata=metadata,
        **layout,
    )
