"""Projectors built once per process from a small picklable :class:`ProjectorSpec`.

The task graph carries the spec (a design's JSON or a PSF file's path, a few kB), never the
projector or the PSF stack: each worker builds the projector on its first task and keeps it
in a per-process cache keyed by :attr:`ProjectorSpec.key` (the design's content hash, or the
PSF file's path, size and modification time), so later tasks on that worker reuse it.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections import Counter, OrderedDict
from dataclasses import asdict, dataclass
from pathlib import Path

import torch

from lfm_studio.engine.design import Design, design_from_json, design_to_json, resolve_design
from lfm_studio.engine.simulation import ImagingSetup, imaging_setup, simulate_psf
from lfm_studio.engine.systems.kinds import kind_of
from lfm_studio.engine.types import JSONValue

KINDS = ("design", "psf")


@dataclass(frozen=True)
class BuiltProjector:
    """A projector with its volume grid, the PSF depths (m) and the design JSON (None if unknown)."""

    setup: ImagingSetup
    depths: tuple[float, ...]
    design_json: str | None


CACHE_SIZE = 2  # projectors kept per process (one run needs one; a second covers a switch)
_CACHE: OrderedDict[str, BuiltProjector] = OrderedDict()
#: How many times this process built each projector (tests check "once per worker").
BUILDS: Counter[str] = Counter()


@dataclass(frozen=True)
class ProjectorSpec:
    """How to build a projector: ``kind="design"`` simulates the PSF of ``design_json``
    (``crop``: camera pixels kept around the axis); ``kind="psf"`` reads the PSF TIFF ``path``.
    ``field_of_view`` (m) sets the volume's lateral extent; ``dtype``: "float32" or "float64"."""

    kind: str
    design_json: str | None = None
    path: str | None = None
    stamp: str = ""  # a PSF file's size and mtime: a rewritten file is a new key
    crop: int | None = None
    field_of_view: float | None = None
    dtype: str = "float32"

    @property
    def key(self) -> str:
        """Content key of the projector (SHA-256 of the spec's fields)."""
        text = json.dumps(asdict(self), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()

    def describe(self) -> dict[str, JSONValue]:
        """JSON-ready record for the output's metadata (the design JSON is stored separately)."""
        return {k: v for k, v in asdict(self).items() if k != "design_json"}


def projector_spec(
    design_or_psf: Design | str | os.PathLike,
    *,
    crop: int | None = None,
    field_of_view: float | None = None,
    dtype: str = "float32",
) -> ProjectorSpec:
    """The spec of a :class:`Design`, a preset name / design file, or a PSF stack TIFF."""
    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64'; got {dtype!r}.")
    if isinstance(design_or_psf, Design):
        return ProjectorSpec(
            "design",
            design_json=design_to_json(design_or_psf),
            crop=crop,
            field_of_view=field_of_view,
            dtype=dtype,
        )
    path = Path(design_or_psf).expanduser()
    if path.suffix.lower() in (".tif", ".tiff"):
        if not path.is_file():
            raise FileNotFoundError(f"PSF stack {path} does not exist. Fix: check the path.")
        if crop is not None:
            raise ValueError(f"crop={crop} applies to a design, not to the PSF stack {path}. Fix: drop it.")
        info = path.stat()
        stamp = f"{info.st_size}:{info.st_mtime_ns}"
        return ProjectorSpec(
            "psf", path=str(path.resolve()), stamp=stamp, crop=crop, field_of_view=field_of_view, dtype=dtype
        )
    return ProjectorSpec(
        "design", design_json=design_to_json(resolve_design(design_or_psf)), crop=crop,
        field_of_view=field_of_view, dtype=dtype,
    )  # fmt: skip


def planned_image_shape(spec: ProjectorSpec) -> tuple[int, int] | None:
    """The ``(Py, Px)`` pixels the projector of a design spec will image, known before its PSF is
    simulated (:meth:`SystemKind.image_shape`); ``None`` for a PSF file (known once it is read)."""
    if spec.kind != "design":
        return None
    design = design_from_json(spec.design_json or "", origin="the video's design")
    return kind_of(design).image_shape(design, crop=spec.crop)


def _build(spec: ProjectorSpec) -> BuiltProjector:
    if spec.kind == "design":
        design = design_from_json(spec.design_json or "", origin="the video's design")
        stack = simulate_psf(design, crop=spec.crop, dtype=spec.dtype)
    else:
        from lfm_studio.engine.io import read_psf_stack

        if spec.path is None:
            raise ValueError("a PSF projector spec needs the PSF stack's path")
        stack = read_psf_stack(spec.path, dtype=getattr(torch, spec.dtype))
    attached = stack.design if isinstance(stack.design, Design) else None
    design_json = spec.design_json or (design_to_json(attached) if attached is not None else None)
    return BuiltProjector(imaging_setup(stack, field_of_view=spec.field_of_view), stack.depths, design_json)


def cached_projector(spec: ProjectorSpec) -> BuiltProjector:
    """The projector of ``spec``, built on the first call in this process and kept."""
    key = spec.key
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    built = _build(spec)
    BUILDS[key] += 1
    _CACHE[key] = built
    while len(_CACHE) > CACHE_SIZE:
        _CACHE.popitem(last=False)
    return built
