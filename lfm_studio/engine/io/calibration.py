"""Physical sampling of TIFFs written by other tools (Fiji, Micro-Manager, tifffile).

Looks, in order, at the ImageJ description (``unit``, ``spacing``) with the TIFF
X/YResolution tags, at OME-XML ``PhysicalSize*`` attributes, and at plain TIFF
resolution tags in centimetres, millimetres or micrometres. Resolutions in inches
(or without a unit) are ignored: they are print settings (72 dpi), never a
microscope's sampling.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import tifffile

#: Length units as ImageJ / OME write them, in metres.
_UNITS = {
    "m": 1.0,
    "cm": 1e-2,
    "mm": 1e-3,
    "um": 1e-6,
    "µm": 1e-6,
    "μm": 1e-6,
    "\\u00b5m": 1e-6,
    "micron": 1e-6,
    "microns": 1e-6,
    "micrometer": 1e-6,
    "nm": 1e-9,
    "nanometer": 1e-9,
}
_TIFF_RESUNIT = {3: 1e-2, 4: 1e-3, 5: 1e-6}  # CENTIMETER, MILLIMETER, MICROMETER


@dataclass(frozen=True)
class Calibration:
    """Voxel/pixel spacing found in a file, metres; ``None`` where the file says nothing."""

    dz: float | None = None
    dy: float | None = None
    dx: float | None = None


def _unit_scale(unit: object) -> float | None:
    if not isinstance(unit, str):
        return None
    return _UNITS.get(unit.strip().lower())


def _positive(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) and value > 0 else None


def _pixel_sizes(page: tifffile.TiffPage, scale: float) -> tuple[float | None, float | None]:
    sizes: list[float | None] = []
    for tag in ("YResolution", "XResolution"):
        item = page.tags.get(tag)
        if item is None:
            sizes.append(None)
            continue
        num, den = item.value
        sizes.append(_positive(scale * den / num) if num else None)
    return sizes[0], sizes[1]


def _from_imagej(tif: tifffile.TiffFile) -> Calibration | None:
    meta = tif.imagej_metadata or {}
    scale = _unit_scale(meta.get("unit"))
    if scale is None:
        return None
    dy, dx = _pixel_sizes(tif.pages.first, scale)
    spacing = meta.get("spacing")
    dz = _positive(float(spacing) * scale) if isinstance(spacing, (int, float)) else None
    return Calibration(dz=dz, dy=dy, dx=dx)


def _from_ome(tif: tifffile.TiffFile) -> Calibration | None:
    try:
        root = ET.fromstring(tif.ome_metadata or "")
    except ET.ParseError:
        return None
    pixels = next((el for el in root.iter() if el.tag.endswith("Pixels")), None)
    if pixels is None:
        return None
    sizes = {}
    for axis in "ZYX":
        value = pixels.get(f"PhysicalSize{axis}")
        scale = _unit_scale(pixels.get(f"PhysicalSize{axis}Unit", "µm"))
        sizes[axis] = _positive(float(value) * scale) if value is not None and scale is not None else None
    return Calibration(dz=sizes["Z"], dy=sizes["Y"], dx=sizes["X"])


def read_calibration(tif: tifffile.TiffFile) -> Calibration:
    """The spacing a foreign TIFF declares (ImageJ, then OME, then TIFF tags)."""
    if tif.is_imagej:
        found = _from_imagej(tif)
        if found is not None:
            return found
    if tif.is_ome:
        found = _from_ome(tif)
        if found is not None:
            return found
    unit = tif.pages.first.tags.get("ResolutionUnit")
    scale = _TIFF_RESUNIT.get(int(unit.value)) if unit is not None else None
    if scale is None:
        return Calibration()
    dy, dx = _pixel_sizes(tif.pages.first, scale)
    return Calibration(dy=dy, dx=dx)
