"""The lfm_studio header embedded in our TIFF files, and the errors of reading them.

Where it lives: the JSON text below is the ImageJ ``Info`` property (ImageJ
metadata tag 50839, shown by Fiji under *Image > Show Info* and kept when Fiji
re-saves the file). It survives a tifffile round trip and leaves the ImageJ
hyperstack description (axes, spacing, unit) untouched, so Fiji and napari read
the physical scale without knowing about us.

Schema (version 1), keys carry their unit::

    {"format": "lfm_studio", "kind": "psf_stack" | "volume" | "image",
     "schema_version": 1, "shape": [...], "axes": "ZYX", "source_dtype": "float64",
     "depths_um": [...], "pixel_size_um": 6.5, "magnification": 20.0,
     "wavelength_nm": 525, "voxel_size_um": [dz, dy, dx],
     "design": {...} | null, "design_kind": "model" | "dict" | null,
     "metadata": {...}}

A PSF stack keeps its typed layout in ``"metadata"``: a conventional-LFM pattern stack
(:class:`ConventionalPatterns`) as ``"kind": "conventional"``, ``"pixels_per_lenslet"``,
``"voxels_per_lenslet"``, ``"reach"`` (one integer per depth) and ``"lenslets"``
(``[Ly, Lx]``); a stack sampled ``k`` times finer than the camera as
``"volume_oversampling": k``. :func:`layout_metadata` writes them and
:func:`split_layout_metadata`, the one parser, reads them back.

Lengths are written as exact decimal shifts of the metre values (``4.8e-05`` m is
written ``48`` um), so reading gives back the identical float64 (no 1-ulp drift
from multiplying by 1e6 and dividing again).
"""

from __future__ import annotations

import importlib
import inspect
import json
import uuid
from decimal import Decimal
from typing import Any

from lfm_studio.engine.psf_stack import ConventionalPatterns

FORMAT_NAME = "lfm_studio"
SCHEMA_VERSION = 1
KINDS = ("psf_stack", "volume", "image")

#: Power-of-ten exponent of each unit suffix used in header keys.
_UNIT_EXPONENT = {"um": 6, "nm": 9}

_PATTERN_KIND = "conventional"  # the "kind" word of a pattern stack's metadata
_PATTERN_KEYS = ("pixels_per_lenslet", "voxels_per_lenslet", "reach", "lenslets")
_OVERSAMPLING_KEY = "volume_oversampling"


class MissingMetadataError(ValueError):
    """A TIFF lacks sampling information that the caller must then provide.

    Attributes
    ----------
    path : str
        The file that was read.
    missing : tuple of str
        Names of the keyword arguments that would supply what is missing
        (e.g. ``("pixel_size", "depths")``), so a CLI can map them to its flags.
    """

    def __init__(self, path: str, missing: list[str], hint: str, *, what: str | None = None):
        self.path = str(path)
        self.missing = tuple(missing)
        super().__init__(f"{path} has no {what or ', '.join(missing)}. {hint}")


class HeaderError(ValueError):
    """The lfm_studio header of a TIFF is of the wrong kind, too new or malformed."""


def _raw_number(value: float, unit: str) -> str:
    """Exact decimal text of ``value`` (SI) expressed in ``unit`` (``"um"``/``"nm"``)."""
    return format(Decimal(repr(float(value))).scaleb(_UNIT_EXPONENT[unit]), "f")


def _from_unit(value: Decimal, unit: str) -> float:
    """Inverse of :func:`_raw_number`: exact decimal in ``unit`` -> float64 SI."""
    return float(Decimal(value).scaleb(-_UNIT_EXPONENT[unit]))


def design_to_json(design: Any) -> Any:
    """JSON object of a design: ``model_dump_json()`` of a pydantic model, or a dict as is."""
    if design is None:
        return None
    if hasattr(design, "model_dump_json"):
        return json.loads(design.model_dump_json())
    if isinstance(design, dict):
        json.dumps(design)  # raises TypeError naming the offending value
        return design
    raise TypeError(
        f"Cannot store a design of type {type(design).__name__}: expected a Design (with "
        "model_dump_json()) or a JSON-serialisable dict."
    )


def design_kind(design: Any) -> str | None:
    """``"model"`` for a Design object, ``"dict"`` for a plain dict, ``None`` for no design."""
    if design is None:
        return None
    return "model" if hasattr(design, "model_dump_json") else "dict"


def design_from_header(obj: Any, *, kind: str | None, rebuild: bool, path: str) -> Any:
    """Rebuild a Design from its JSON object when it was saved from one and
    ``lfm_studio.engine.design`` provides ``design_from_json``; otherwise (or with
    ``rebuild=False``) return the JSON dict. A design saved as a plain dict stays a dict."""
    if obj is None or not rebuild or kind == "dict":
        return obj
    try:
        module = importlib.import_module("lfm_studio.engine.design")
    except ModuleNotFoundError as exc:
        if exc.name not in ("lfm_studio.engine.design", "lfm_studio.engine"):
            raise
        return obj
    builder = getattr(module, "design_from_json", None)
    if builder is None:
        return obj
    # design_from_json(text, *, origin=...) names the source in its messages when it can.
    named = "origin" in inspect.signature(builder).parameters
    try:
        return builder(json.dumps(obj), **({"origin": f"{path} (embedded design)"} if named else {}))
    except Exception as exc:
        raise HeaderError(
            f"{path}: the embedded design could not be rebuilt ({exc}). "
            "Fix: read it with rebuild_design=False to get the design as a JSON dict."
        ) from exc


def layout_metadata(patterns: ConventionalPatterns | None, volume_oversampling: int = 1) -> dict[str, Any]:
    """The JSON-serialisable metadata entries of a PSF stack's typed layout (``{}`` for plain PSFs)."""
    entries: dict[str, Any] = {}
    if volume_oversampling != 1:
        entries[_OVERSAMPLING_KEY] = int(volume_oversampling)
    if patterns is None:
        return entries
    return {
        **entries,
        "kind": _PATTERN_KIND,
        "pixels_per_lenslet": patterns.pixels_per_lenslet,
        "voxels_per_lenslet": patterns.voxels_per_lenslet,
        "reach": list(patterns.reach),
        "lenslets": list(patterns.lenslets),
    }


def split_layout_metadata(
    metadata: dict[str, Any] | None, *, where: str = "metadata"
) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(layout, rest)``: the typed layout stored by :func:`layout_metadata` as :class:`PSFStack`
    keyword arguments (``patterns``, ``volume_oversampling``; empty for plain PSFs) and the
    remaining free-form entries. ``where`` names the source in errors."""
    rest = dict(metadata or {})
    layout: dict[str, Any] = {}
    if _OVERSAMPLING_KEY in rest:
        layout["volume_oversampling"] = rest.pop(_OVERSAMPLING_KEY)
    if rest.get("kind") != _PATTERN_KIND:
        return layout, rest
    missing = [key for key in _PATTERN_KEYS if key not in rest]
    if missing:
        raise HeaderError(
            f"{where}: a conventional pattern stack lacks {', '.join(missing)} in its metadata. "
            "Fix: re-simulate the PSF with lfm-studio simulate."
        )
    values = {key: rest.pop(key) for key in _PATTERN_KEYS}
    del rest["kind"]
    try:
        layout["patterns"] = ConventionalPatterns(
            pixels_per_lenslet=values["pixels_per_lenslet"],
            voxels_per_lenslet=values["voxels_per_lenslet"],
            reach=tuple(values["reach"]),
            lenslets=tuple(values["lenslets"]),
        )
    except (TypeError, ValueError) as exc:
        raise HeaderError(f"{where}: malformed conventional pattern layout ({exc}).") from exc
    return layout, rest


def encode_header(kind: str, fields: dict[str, Any], units: dict[str, str]) -> str:
    """JSON text of a header of ``kind``.

    ``fields`` maps keys to values; a key listed in ``units`` (key -> unit) holds a
    float or a list of floats in metres, written exactly in that unit.
    """
    header: dict[str, Any] = {"format": FORMAT_NAME, "kind": kind, "schema_version": SCHEMA_VERSION}
    raw: dict[str, str] = {}
    token = uuid.uuid4().hex
    for key, value in fields.items():
        if key in units and value is not None:
            values = value if isinstance(value, (list, tuple)) else [value]
            texts = [_raw_number(v, units[key]) for v in values]
            placeholder = f"@@{token}:{key}@@"
            raw[placeholder] = f"[{', '.join(texts)}]" if isinstance(value, (list, tuple)) else texts[0]
            header[key] = placeholder
        else:
            header[key] = value
    try:
        text = json.dumps(header, indent=1)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"metadata must be JSON-serialisable (str, numbers, lists, dicts): {exc}") from exc
    for placeholder, number in raw.items():
        text = text.replace(json.dumps(placeholder), number)
    return text


def decode_header(text: str | None, path: str, units: dict[str, str]) -> dict[str, Any] | None:
    """Parse an Info text; ``None`` if it is not an lfm_studio header.

    Keys listed in ``units`` come back as float64 metres (or lists of them).
    """
    if not text or not text.lstrip().startswith("{"):
        return None
    try:
        header = json.loads(text)
        exact = json.loads(text, parse_float=Decimal, parse_int=Decimal)
    except json.JSONDecodeError:
        return None
    if not isinstance(header, dict) or header.get("format") != FORMAT_NAME:
        return None
    version = header.get("schema_version")
    if not isinstance(version, int) or version < 1:
        raise HeaderError(f"{path}: lfm_studio header has an invalid schema_version {version!r}.")
    if version > SCHEMA_VERSION:
        raise HeaderError(
            f"{path} was written with lfm_studio TIFF schema {version}; this version reads up to "
            f"{SCHEMA_VERSION}. Fix: update lfm_studio."
        )
    for key, unit in units.items():
        value = exact.get(key)
        if value is None:
            continue
        header[key] = (
            [_from_unit(v, unit) for v in value] if isinstance(value, list) else _from_unit(value, unit)
        )
    return header


def require_kind(header: dict[str, Any], kind: str, path: str) -> None:
    """Raise :class:`HeaderError` if the file holds another kind of data."""
    found = str(header.get("kind"))
    if found != kind:
        reader = {"psf_stack": "read_psf_stack", "volume": "read_volume", "image": "read_image"}.get(
            found, "?"
        )
        raise HeaderError(
            f"{path} holds an lfm_studio {found!r}, not a {kind!r}. Fix: read it with {reader}()."
        )
