"""Manufacturability constraints: a design either passes, is repaired, or gets a named reason.

A constraint's :meth:`check` returns ``None`` (feasible) or an :class:`Infeasible` with a
short ``reason`` code (recorded in the study, counted in reports) and a message naming the
values. :class:`FocalLengthCatalogue` is a repair: it snaps every lenslet focal length to
the nearest stock value before the checks. Points the design itself refuses (the model
validation: overlapping apertures, a lenslet centre outside the pupil, a sub-image off the
sensor...) become an :class:`Infeasible` through :func:`infeasible_from_error`, never a crash.

Lengths are in the design's units: micrometres on the MLA plane and the sensor, millimetres
for focal lengths.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

from pydantic import ValidationError

from lfm_studio.engine.design import Design
from lfm_studio.engine.design.errors import fmt
from lfm_studio.engine.design.geometry import disc_overlaps, list_pairs
from lfm_studio.engine.systems.kinds import kind_of


@dataclass(frozen=True)
class Infeasible:
    """Why a candidate cannot be built or made.

    reason : a short code (``lenslet_overlap``, ``outside_pupil``, ``sub_image_off_sensor``,
        ``sub_image_overlap``, ``lenslet_too_small``, ``requirement_failed``, ``invalid_design``).
    message : what failed, with the values.
    """

    reason: str
    message: str

    def __str__(self) -> str:
        return f"{self.reason}: {self.message}"


class Constraint(Protocol):
    """A check of a built design (``None`` = feasible)."""

    @property
    def name(self) -> str: ...

    def check(self, design: Design) -> Infeasible | None: ...


# What each infeasibility code means, one short sentence each (docs/optimize.md lists where each comes from).
REASONS: dict[str, str] = {
    "lenslet_overlap": "Two lenslet apertures overlap.",
    "outside_pupil": "A lenslet (its centre, or part of its aperture) lies outside the pupil image at the MLA.",
    "outside_array_aperture": "A lenslet lies beyond the MLA's array aperture.",
    "sub_image_off_sensor": "A sub-image (its centre, or part of it) falls off the camera sensor.",
    "sub_image_overlap": "Two sub-images overlap on the sensor by more than half a pixel.",
    "unbounded_field": "No field number or field stop: the sub-images cannot be checked.",
    "lenslet_too_small": "A lenslet aperture is below the minimum lenslet size.",
    "requirement_failed": "A closed-form requirement (e.g. the zebrafish requirements) fails.",
    "evaluation_refused": "An objective refused the candidate (e.g. a reconstruction rejected as all zero).",
    "invalid_design": "The design's own validation refused the candidate (see its message).",
    "layout_refused": "Algorithm 2 refused the merge: the block lies outside the pupil, cuts through a lenslet "
    "it does not contain, or overlaps its own symmetric image.",
    "not_finite": "The objective came out infinite or NaN at this point.",
}


# Phrases of the design's own refusals (engine/design) and the reason code each means.
_ERROR_REASONS = (
    ("must not overlap", "lenslet_overlap"),
    ("inside the pupil image", "outside_pupil"),
    ("inside the array aperture", "outside_array_aperture"),
    ("sub-images must be centred", "sub_image_off_sensor"),
)


def error_text(error: Exception) -> str:
    """The message of a refusal: pydantic's errors as ``location: message`` (without its boilerplate)."""
    if isinstance(error, ValidationError):
        return "; ".join(
            f"{'.'.join(str(p) for p in e['loc']) or 'design'}: {str(e['msg']).removeprefix('Value error, ')}"
            for e in error.errors()
        )
    return str(error)


def infeasible_from_error(error: Exception) -> Infeasible:
    """An :class:`Infeasible` for a design the model validation refused (its message kept whole)."""
    text = error_text(error)
    for phrase, reason in _ERROR_REASONS:
        if phrase in text:
            return Infeasible(reason, text)
    return Infeasible("invalid_design", text)


@dataclass(frozen=True)
class FocalLengthCatalogue:
    """Stock lenslet focal lengths (mm): :meth:`snap` moves every lenslet to the nearest one."""

    focal_lengths_mm: tuple[float, ...]
    name: str = "focal_length_catalogue"

    def __post_init__(self) -> None:
        if not self.focal_lengths_mm or any(not (math.isfinite(f) and f > 0) for f in self.focal_lengths_mm):
            raise ValueError(
                f"focal_lengths_mm must list positive focal lengths in mm; got {self.focal_lengths_mm}. "
                "Fix: e.g. (10, 16.8, 20, 26)."
            )

    def nearest(self, focal_length_mm: float) -> float:
        return min(self.focal_lengths_mm, key=lambda f: (abs(f - focal_length_mm), f))

    def snap(self, design: Design) -> Design:
        """``design`` with every lenslet focal length replaced by the nearest catalogue value."""
        mla = design.mla
        if mla.layout == "regular":
            return design.updated(
                mla=mla.model_copy(update={"focal_length_mm": self.nearest(mla.focal_length_mm)})
            )
        lenslets = tuple(
            lens.model_copy(update={"focal_length_mm": self.nearest(lens.focal_length_mm)})
            for lens in mla.lenslets
        )
        return design.updated(
            mla=type(mla)(lenslets=lenslets, array_aperture_diameter_um=mla.array_aperture_diameter_um)
        )


@dataclass(frozen=True)
class MinimumLensletSize:
    """Every lenslet aperture (diameter or side) at least ``min_aperture_um`` micrometres."""

    min_aperture_um: float
    name: str = "minimum_lenslet_size"

    def check(self, design: Design) -> Infeasible | None:
        small = [
            f"{lens.describe(i)} {fmt(lens.aperture_diameter_um)} um"
            for i, lens in enumerate(design.mla.lenslets)
            if lens.aperture_diameter_um < self.min_aperture_um - 1e-9
        ]
        if not small:
            return None
        return Infeasible(
            "lenslet_too_small",
            f"apertures below the {fmt(self.min_aperture_um)} um minimum: {list_pairs(small)}",
        )


@dataclass(frozen=True)
class InsidePupil:
    """Fourier LFM: every lenslet aperture entirely inside the pupil image at the MLA (no vignetting)."""

    name: str = "inside_pupil"

    def check(self, design: Design) -> Infeasible | None:
        if design.pupil_diameter_at_mla is None:
            return None
        radius_um = design.pupil_diameter_at_mla / 2.0 * 1e6
        out = [
            f"{lens.describe(i)} reaches {fmt(lens.reach_um)} um"
            for i, lens in enumerate(design.mla.lenslets)
            if lens.reach_um > radius_um + 1e-5
        ]
        if not out:
            return None
        return Infeasible(
            "outside_pupil", f"the pupil image has radius {fmt(radius_um)} um; {list_pairs(out)}"
        )


def _sub_image_centres_um(design: Design) -> list[tuple[float, float]]:
    return [lens.center_um for lens in design.mla.lenslets]


@dataclass(frozen=True)
class SubImagesOnSensor:
    """Every sub-image (disc of the design's sub-image radius about its lenslet centre) fully on the sensor."""

    name: str = "sub_images_on_sensor"

    def check(self, design: Design) -> Infeasible | None:
        radius = design.sub_image_radius
        if radius is None:
            return Infeasible(
                "unbounded_field",
                "the field of view is unlimited (no field number or field stop): sub-images unbounded",
            )
        r_um = radius * 1e6
        half_w, half_h = (s / 2.0 * 1e6 for s in design.camera.sensor_size)
        slack = 0.5 * design.camera.pixel_pitch_um
        off = [
            f"lenslet {i} at ({fmt(x)}, {fmt(y)}) um"
            for i, (x, y) in enumerate(_sub_image_centres_um(design))
            if abs(x) + r_um > half_w + slack or abs(y) + r_um > half_h + slack
        ]
        if not off:
            return None
        return Infeasible(
            "sub_image_off_sensor",
            f"sub-images {fmt(2 * r_um)} um across leave the {fmt(2 * half_w)} x {fmt(2 * half_h)} um sensor: "
            f"{list_pairs(off)}",
        )


@dataclass(frozen=True)
class NoSubImageOverlap:
    """No two sub-images overlap on the sensor by more than half a pixel (:func:`disc_overlaps`)."""

    name: str = "no_sub_image_overlap"

    def check(self, design: Design) -> Infeasible | None:
        radius = design.sub_image_radius
        if radius is None:
            return Infeasible(
                "unbounded_field",
                "the field of view is unlimited (no field number or field stop): sub-images unbounded",
            )
        centres = _sub_image_centres_um(design)
        found = disc_overlaps(centres, radius * 1e6, 0.5 * design.camera.pixel_pitch_um)
        if not found:
            return None
        pairs = [f"lenslets {i} and {j} by {fmt(depth)} um" for i, j, depth in found]
        return Infeasible("sub_image_overlap", f"sub-images overlap on the sensor: {list_pairs(pairs)}")


DEFAULT_CONSTRAINTS: tuple[Constraint, ...] = (InsidePupil(), SubImagesOnSensor(), NoSubImageOverlap())
"""What every Fourier-LFM candidate must satisfy unless told otherwise (overlapping lenslet
apertures are refused by the design itself)."""


def first_violation(design: Design, constraints: Sequence[Constraint]) -> Infeasible | None:
    """The first constraint ``design`` breaks, or None."""
    for constraint in constraints:
        found = constraint.check(design)
        if found is not None:
            return found
    return None


def default_constraints(design: Design) -> tuple[Constraint, ...]:
    """:data:`DEFAULT_CONSTRAINTS` for a design whose MLA sits on the pupil (Fourier LFM), else none."""
    return DEFAULT_CONSTRAINTS if kind_of(design).mla_at_pupil else ()
