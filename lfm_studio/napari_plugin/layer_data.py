"""Engine objects <-> napari image layers (Qt-free): scale, translate, units and metadata.

A layer made here carries in ``layer.metadata`` everything needed to rebuild the engine
object exactly (lengths both in metres, exact, and in the units people read)::

    kind            "psf_stack" | "light_field" | "volume"
    psf_stack       depths_m, depths_um, pixel_size_m, pixel_size_um (sensor pitch),
                    magnification, object_pixel_size_um, wavelength_m, wavelength_nm,
                    design (design JSON object or None), design_kind, metadata
    light_field     pixel_size_m, pixel_size_um, metadata
    volume          voxel_size_m, voxel_size_um (dz, dy, dx), depths_m, depths_um, metadata

Scales are micrometres. Light-field images and PSF stacks use the *sensor* pixel pitch,
so a PSF lies on the camera image it explains; volumes use object-space voxels. The
depth axis is the sample-side depth step, translated so napari's z coordinate reads the
depth itself; lateral axes are centred on the optical axis (pixel ``N // 2`` at 0).
Conventional-LFM pattern stacks ``(S, S, Z, H, H)`` are 5-D layers (two lenslet-position
axes, then depth). The metadata is authoritative: the writer and the reconstruct widget
rebuild engine objects from it, not from the (editable) layer scale.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import torch

from lfm_studio.engine.io import LightFieldImage, Volume
from lfm_studio.engine.io.metadata import (
    design_kind,
    design_to_json,
    layout_metadata,
    split_layout_metadata,
)
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.units import nm, um

LayerData = tuple[Any, dict[str, Any], str]
KINDS = ("psf_stack", "light_field", "volume")


class LayerError(ValueError):
    """A layer cannot be turned into the engine object asked for; the message names the layer and a fix."""


def kind_of(metadata: dict[str, Any] | None) -> str | None:
    """The lfm_studio kind recorded in a layer's metadata (None for other layers)."""
    kind = (metadata or {}).get("kind")
    return kind if kind in KINDS else None


def _micrometres(values: tuple[float, ...]) -> list[float]:
    return [v / um for v in values]


def _depth_axis(depths: tuple[float, ...], fallback_step: float) -> tuple[float, float]:
    """(scale, translate) in um of a depth axis: the mean step and the first depth."""
    step = (depths[-1] - depths[0]) / (len(depths) - 1) if len(depths) > 1 else fallback_step
    return step / um, depths[0] / um


def _centred(n: int, step_um: float) -> float:
    return -(n // 2) * step_um


def _as_numpy(data: torch.Tensor) -> np.ndarray:
    return data.detach().cpu().numpy()


def psf_layer_data(stack: PSFStack, *, name: str, source: str | None = None) -> LayerData:
    """LayerData of a PSF stack ``(Z, Y, X)`` (or conventional patterns ``(S, S, Z, H, H)``)."""
    if stack.data.ndim not in (3, 5):
        raise LayerError(
            f"PSF stack {name!r} has shape {tuple(stack.data.shape)}; napari layers are made for (Z, Y, X) "
            "Fourier stacks and (S, S, Z, H, H) conventional pattern stacks."
        )
    ny, nx = stack.data.shape[-2:]
    pixel_um = stack.pixel_size / um
    dz_um, z0_um = _depth_axis(stack.depths, stack.object_pixel_size)
    lead = stack.data.ndim - 3
    metadata = {
        "kind": "psf_stack",
        "depths_m": list(stack.depths),
        "depths_um": _micrometres(stack.depths),
        "pixel_size_m": stack.pixel_size,
        "pixel_size_um": pixel_um,
        "magnification": stack.magnification,
        "object_pixel_size_um": stack.object_pixel_size / um,
        "wavelength_m": stack.wavelength,
        "wavelength_nm": stack.wavelength / nm,
        "design": design_to_json(stack.design),
        "design_kind": design_kind(stack.design),
        "metadata": {**stack.metadata, **layout_metadata(stack.patterns, stack.volume_oversampling)},
        "source": source,
    }
    meta = {
        "name": name,
        "scale": (1.0,) * lead + (dz_um, pixel_um, pixel_um),
        "translate": (0.0,) * lead + (z0_um, _centred(ny, pixel_um), _centred(nx, pixel_um)),
        "units": ("um",) * (lead + 3),
        "axis_labels": (*("lenslet y", "lenslet x")[:lead], "depth", "y", "x"),
        "colormap": "magma",
        "gamma": 0.6,
        "metadata": metadata,
    }
    return _as_numpy(stack.data), meta, "image"


def light_field_layer_data(image: LightFieldImage, *, name: str, source: str | None = None) -> LayerData:
    """LayerData of a camera image ``(Y, X)`` or frames ``(T, Y, X)`` at the sensor pixel pitch."""
    ny, nx = image.data.shape[-2:]
    pixel_um = image.pixel_size / um
    lead = image.data.ndim - 2
    meta = {
        "name": name,
        "scale": (1.0,) * lead + (pixel_um, pixel_um),
        "translate": (0.0,) * lead + (_centred(ny, pixel_um), _centred(nx, pixel_um)),
        "units": ("um",) * (lead + 2),
        "axis_labels": (*("frame",)[:lead], "y", "x"),
        "colormap": "gray",
        "metadata": {
            "kind": "light_field",
            "pixel_size_m": image.pixel_size,
            "pixel_size_um": pixel_um,
            "metadata": dict(image.metadata),
            "source": source,
        },
    }
    return _as_numpy(image.data), meta, "image"


def volume_layer_data(
    volume: Volume, *, name: str, source: str | None = None, colormap: str = "inferno"
) -> LayerData:
    """LayerData of a volume ``(Z, Y, X)`` or ``(T, Z, Y, X)`` in object space (voxel size in um)."""
    dz, dy, dx = volume.voxel_size
    ny, nx = volume.data.shape[-2:]
    depths = volume.depth_values()
    _, z0_um = _depth_axis(depths, dz)
    lead = volume.data.ndim - 3
    meta = {
        "name": name,
        "scale": (1.0,) * lead + (dz / um, dy / um, dx / um),
        "translate": (0.0,) * lead + (z0_um, _centred(ny, dy / um), _centred(nx, dx / um)),
        "units": ("um",) * (lead + 3),
        "axis_labels": (*("frame",)[:lead], "depth", "y", "x"),
        "colormap": colormap,
        "metadata": {
            "kind": "volume",
            "voxel_size_m": list(volume.voxel_size),
            "voxel_size_um": _micrometres(volume.voxel_size),
            "depths_m": None if volume.depths is None else list(volume.depths),
            "depths_um": None if volume.depths is None else _micrometres(volume.depths),
            "metadata": dict(volume.metadata),
            "source": source,
        },
    }
    return _as_numpy(volume.data), meta, "image"


# ----- back to engine objects -----


def _tensor(data: Any, name: str) -> torch.Tensor:
    array = np.asarray(data)
    if array.dtype.kind not in "fiub":
        raise LayerError(
            f"layer {name!r} holds {array.dtype} data; expected real numbers (a grayscale image)."
        )
    return torch.from_numpy(np.array(array, dtype=np.float32))


def _require(metadata: dict[str, Any], keys: tuple[str, ...], name: str) -> None:
    missing = [key for key in keys if metadata.get(key) is None]
    if missing:
        raise LayerError(
            f"layer {name!r} lacks {', '.join(missing)} in its metadata. Fix: open the file with the "
            "lfm-studio reader (File > Open with Plugin > lfm-studio) or recompute it with lfm_studio."
        )


def design_of(metadata: dict[str, Any], name: str = "layer") -> Any:
    """The Design recorded in a PSF layer's metadata (a dict stays a dict; None if there is none)."""
    obj = metadata.get("design")
    if obj is None or metadata.get("design_kind") == "dict":
        return obj
    from lfm_studio.engine.design import design_from_json

    try:
        return design_from_json(json.dumps(obj), origin=f"the design in layer {name!r}")
    except ValueError as error:
        raise LayerError(f"layer {name!r}: its design could not be rebuilt ({error}).") from error


def stack_from_layer(data: Any, metadata: dict[str, Any], *, name: str) -> PSFStack:
    """Rebuild the :class:`PSFStack` of a PSF layer made by :func:`psf_layer_data`."""
    if kind_of(metadata) != "psf_stack":
        raise LayerError(
            f"layer {name!r} is not an lfm_studio PSF stack (kind {metadata.get('kind')!r}). Fix: pick a PSF "
            "layer from 'Simulate PSF', the sample data, or a PSF TIFF opened with the lfm-studio reader."
        )
    _require(metadata, ("depths_m", "pixel_size_m", "magnification", "wavelength_m"), name)
    try:
        layout, extra = split_layout_metadata(metadata.get("metadata"), where=f"layer {name!r}")
        return PSFStack(
            data=_tensor(data, name),
            depths=tuple(metadata["depths_m"]),
            pixel_size=float(metadata["pixel_size_m"]),
            magnification=float(metadata["magnification"]),
            wavelength=float(metadata["wavelength_m"]),
            design=design_of(metadata, name),
            metadata=extra,
            **layout,
        )
    except LayerError:
        raise
    except ValueError as error:
        raise LayerError(f"layer {name!r}: {error}") from error


def square_pixel_um(scale: Any, name: str) -> float:
    """The lateral pixel size (um) of a layer without our metadata, from its last two scale entries."""
    dy, dx = (float(s) for s in tuple(scale)[-2:])
    if not math.isclose(dy, dx, rel_tol=1e-6):
        raise LayerError(
            f"layer {name!r} has non-square pixels (scale y {dy:g}, x {dx:g} um). Fix: set equal y and x "
            "scales (Layer > Scale) or resample the image."
        )
    return dx


def image_from_layer(data: Any, metadata: dict[str, Any], scale: Any, *, name: str) -> LightFieldImage:
    """The :class:`LightFieldImage` of an image layer: our metadata, or else the layer scale read as um."""
    kind = kind_of(metadata)
    if kind not in (None, "light_field"):
        raise LayerError(
            f"layer {name!r} is an lfm_studio {kind}, not a light-field image. Fix: pick the camera image layer."
        )
    tensor = _tensor(data, name)
    if tensor.ndim not in (2, 3):
        raise LayerError(
            f"layer {name!r} has shape {tuple(tensor.shape)}; a light-field image is (Y, X) or frames (T, Y, X)."
        )
    if kind == "light_field":
        _require(metadata, ("pixel_size_m",), name)
        pixel, extra = float(metadata["pixel_size_m"]), dict(metadata.get("metadata") or {})
    else:
        pixel, extra = square_pixel_um(scale, name) * um, {}
    return LightFieldImage(tensor, pixel, extra)


def volume_from_layer(data: Any, metadata: dict[str, Any], scale: Any, *, name: str) -> Volume:
    """The :class:`Volume` of an image layer: our metadata, or else the layer scale ``(dz, dy, dx)`` in um."""
    kind = kind_of(metadata)
    tensor = _tensor(data, name)
    if kind == "volume":
        _require(metadata, ("voxel_size_m",), name)
        depths = metadata.get("depths_m")
        return Volume(
            tensor,
            tuple(metadata["voxel_size_m"]),
            None if depths is None else tuple(depths),
            dict(metadata.get("metadata") or {}),
        )
    if tensor.ndim not in (3, 4):
        raise LayerError(
            f"layer {name!r} has shape {tuple(tensor.shape)}; a volume is (Z, Y, X) or (T, Z, Y, X)."
        )
    voxel = tuple(float(s) * um for s in tuple(scale)[-3:])
    return Volume(tensor, voxel, None, {})
