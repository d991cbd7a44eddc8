"""The design parameters the parameter panel edits, and their labels in the studio's messages (Qt-free).

Each :class:`FieldSpec` names a design value by its path (as in
:func:`~lfm_studio.engine.design.evolve`), the label the user reads, the unit shown and the
input range. The engine's design checks name a value by its key (``"numerical_aperture 1.2
must be below immersion_index 1"``), which suits the CLI and design files; the studio shows
the same messages with the field labels of its parameter panel (:func:`in_field_labels`):
``"Numerical aperture 1.2 must be below immersion index 1"``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from lfm_studio.engine.systems.kinds import CONVENTIONAL, FOURIER, KINDS, SystemKind


@dataclass(frozen=True)
class FieldSpec:
    """One editable value.

    Attributes
    ----------
    path : design path, e.g. ``"objective.numerical_aperture"``.
    label : what the user reads.
    unit : suffix shown in the box ("nm", "µm", "mm", "×", "" ...).
    group : the panel section.
    decimals, minimum, maximum, step : of the input box.
    parts : 1 for a number, 2 for a pair such as ``pixel_count`` (y, x) or ``depth_range_um``.
    integer : whole numbers (pixel counts).
    optional : the minimum means "none" (the design value is None).
    kinds : system kinds where the field applies (default: all).
    tip : tooltip.
    """

    path: str
    label: str
    unit: str
    group: str
    decimals: int = 3
    minimum: float = 0.0
    maximum: float = 1e6
    step: float = 1.0
    parts: int = 1
    integer: bool = False
    optional: bool = False
    kinds: tuple[SystemKind, ...] = KINDS
    tip: str = ""


FIELDS: tuple[FieldSpec, ...] = (
    FieldSpec("wavelength_nm", "Emission wavelength", "nm", "Light", 1, 0.0, 1e5, 5.0,
              tip="Emission wavelength in vacuum (GCaMP: 525 nm)."),
    FieldSpec("objective.magnification", "Magnification", "×", "Objective", 2, 0.0, 1000.0, 1.0,
              tip="Lateral magnification with the tube lens below."),
    FieldSpec("objective.numerical_aperture", "Numerical aperture", "", "Objective", 3, 0.0, 10.0, 0.05,
              tip="NA = n sin(alpha); must stay below the immersion index."),
    FieldSpec("objective.immersion_index", "Immersion index", "", "Objective", 3, 0.0, 10.0, 0.01,
              tip="1.0 air, 1.333 water, 1.515 oil."),
    FieldSpec("objective.tube_lens_focal_length_mm", "Tube lens focal length", "mm", "Objective", 1, 0.0, 1e4, 5.0,
              tip="Olympus 180 mm, Nikon 200 mm, Zeiss 165 mm."),
    FieldSpec("relay.focal_length_mm", "Fourier lens focal length", "mm", "Fourier lens", 1, 0.0, 1e4, 5.0,
              kinds=(FOURIER,), tip="Relay lens that images the back pupil onto the MLA."),
    FieldSpec("relay.field_stop_diameter_mm", "Field stop diameter", "mm", "Fourier lens", 2, 0.0, 1e3, 0.1,
              optional=True, kinds=(FOURIER,), tip="Iris at the native image plane (0 = none)."),
    FieldSpec("mla_to_camera_distance_mm", "MLA to camera distance", "mm", "MLA and camera", 2, 0.0, 1e4, 0.25,
              tip="Distance from the microlens array to the sensor."),
    FieldSpec("camera.pixel_pitch_um", "Pixel pitch", "µm", "MLA and camera", 2, 0.0, 1e3, 0.1),
    FieldSpec("camera.pixel_count", "Pixel count (y, x)", "px", "MLA and camera", 0, 0, 100_000, 64,
              parts=2, integer=True),
    FieldSpec("camera.quantum_efficiency", "Quantum efficiency", "", "MLA and camera", 3, 0.0, 10.0, 0.05,
              tip="Fraction of photons detected, in (0, 1]."),
    FieldSpec("camera.read_noise_e", "Read noise", "e⁻ rms", "MLA and camera", 2, 0.0, 1e4, 0.1),
    FieldSpec("depths.depth_range_um", "Depth range (from, to)", "µm", "Depths", 1, -1e5, 1e5, 10.0, parts=2,
              tip="Source depths below the native focal plane (positive: away from the objective)."),
    FieldSpec("depths.depth_step_um", "Depth step", "µm", "Depths", 2, 0.0, 1e5, 1.0),
    FieldSpec("accuracy.voxels_per_lenslet", "Voxels per lenslet", "", "Computation", 0, 0, 99, 2, integer=True,
              kinds=(CONVENTIONAL,), tip="Lateral volume voxels per lenslet pitch (odd). Finer grids resolve "
              "closer pairs (never below 2 voxels) at the square of the PSF cost."),
    FieldSpec("accuracy.volume_oversampling", "Volume voxels per pixel", "", "Computation", 0, 0, 7, 2,
              integer=True, kinds=(FOURIER,), tip="1, 3, 5 or 7 volume voxels per sensor pixel (the PSF is "
              "sampled to match). Finer grids resolve closer pairs at k² the PSF and volume size."),
)  # fmt: skip

_SHARED_KEYS = frozenset({"focal_length_mm"})  # also a lenslet's key: ambiguous without its path


def _label_names() -> dict[str, str]:
    """Key -> label: each field's full path, and its last part where no other value has that name
    (``focal_length_mm`` is also every lenslet's: only ``relay.focal_length_mm`` is the field's)."""
    names = {spec.path: spec.label for spec in FIELDS}
    last = [spec.path.rsplit(".", 1)[-1] for spec in FIELDS]
    for spec, key in zip(FIELDS, last, strict=True):
        if key not in names and last.count(key) == 1 and key not in _SHARED_KEYS:
            names[key] = spec.label
    return names


LABELS: dict[str, str] = _label_names()
_KEY = re.compile(
    r"(?<![\w.])(" + "|".join(sorted(map(re.escape, LABELS), key=len, reverse=True)) + r")(?![\w])"
)
_SENTENCE_START = re.compile(r"(^|[.;:!?]\s+|\n)$")


def _label_in_sentence(label: str, before: str) -> str:
    """``label`` as it reads at its place: capitalised at a sentence's start, else lower case
    (unless it starts with an acronym such as "MLA")."""
    if _SENTENCE_START.search(before) or label[1:2].isupper():
        return label
    return label[:1].lower() + label[1:]


def in_field_labels(text: str) -> str:
    """``text`` (a design check's message) with each parameter key or path replaced by the label
    of its field in the parameter panel, e.g. ``"depth_step_um must be > 0"`` ->
    ``"Depth step must be > 0"``; other words (and keys no field shows) are left alone."""
    return _KEY.sub(lambda m: _label_in_sentence(LABELS[m.group(1)], text[: m.start()]), text)
