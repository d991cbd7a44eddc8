"""Objective (with its tube lens) and the Fourier / relay lens of a Fourier LFM.

Geometry (paraxial for the relay, Abbe sine condition for the objective): an
infinity-corrected objective of magnification ``M`` used with a tube lens of focal
length ``f_tube`` has ``f_obj = f_tube / M``; a ray leaving the focus at angle
``theta`` in the immersion medium (index ``n``) crosses the back focal plane at
height ``n f_obj sin(theta)``, so the back-pupil diameter is ``2 NA f_obj``.
"""

from __future__ import annotations

import math

from pydantic import model_validator

from lfm_studio.engine.design.base import SpecModel, si
from lfm_studio.engine.design.errors import DesignError, fmt, require_positive


class ObjectiveSpec(SpecModel):
    """An infinity-corrected objective and the tube lens it is used with.

    Attributes
    ----------
    magnification : float
        Lateral magnification with ``tube_lens_focal_length_mm`` (unitless, > 0).
    numerical_aperture : float
        ``n sin(alpha)`` (unitless), strictly below ``immersion_index``.
    immersion_index : float
        Refractive index of the immersion medium (1.0 air, 1.333 water, 1.515 oil); >= 1.
    tube_lens_focal_length_mm : float
        Focal length of the tube lens in mm (Olympus 180, Nikon/Leica 200, Zeiss 165).
    field_number_mm : float or None
        Diameter in mm of the objective's corrected field at the native image plane;
        limits the field of view to ``field_number_mm / magnification`` at the sample.
    """

    magnification: float
    numerical_aperture: float
    immersion_index: float = 1.0
    tube_lens_focal_length_mm: float
    field_number_mm: float | None = None

    @model_validator(mode="after")
    def _check(self) -> ObjectiveSpec:
        require_positive("magnification", self.magnification, "", "e.g. 20 for a 20x objective.")
        require_positive("numerical_aperture", self.numerical_aperture, "", "e.g. 0.5.")
        require_positive(
            "tube_lens_focal_length_mm",
            self.tube_lens_focal_length_mm,
            "mm",
            "Olympus 180, Nikon 200, Zeiss 165.",
        )
        if not (math.isfinite(self.immersion_index) and self.immersion_index >= 1.0):
            raise DesignError(
                f"immersion_index must be >= 1 (vacuum); got {fmt(self.immersion_index)}. "
                "Fix: 1.0 for air, 1.333 for water, 1.515 for oil."
            )
        if self.numerical_aperture >= self.immersion_index:
            raise DesignError(
                f"numerical_aperture {fmt(self.numerical_aperture)} must be below immersion_index "
                f"{fmt(self.immersion_index)} (NA = n sin(alpha) < n); fix: lower the NA or set the immersion "
                "medium the objective is made for (1.333 water, 1.515 oil)."
            )
        if self.numerical_aperture >= self.magnification:
            raise DesignError(
                f"numerical_aperture / magnification (the image-side NA) must be below 1; got "
                f"{fmt(self.numerical_aperture)} / {fmt(self.magnification)}. Fix: check the magnification."
            )
        if self.field_number_mm is not None:
            require_positive("field_number_mm", self.field_number_mm, "mm", "e.g. 22, or leave it out.")
        return self

    @property
    def tube_lens_focal_length(self) -> float:
        """Tube-lens focal length in metres."""
        return si(self.tube_lens_focal_length_mm, "mm")

    @property
    def focal_length(self) -> float:
        """Objective focal length ``f_tube / M`` in metres."""
        return self.tube_lens_focal_length / self.magnification

    @property
    def half_angle(self) -> float:
        """Half-angle of the collection cone in the immersion medium, ``asin(NA / n)``, radians."""
        return math.asin(self.numerical_aperture / self.immersion_index)

    @property
    def back_pupil_diameter(self) -> float:
        """Diameter of the back pupil, ``2 NA f_obj``, in metres."""
        return 2.0 * self.numerical_aperture * self.focal_length

    @property
    def field_of_view_diameter(self) -> float | None:
        """Field of view at the sample allowed by the field number, in metres (None if not given)."""
        if self.field_number_mm is None:
            return None
        return si(self.field_number_mm, "mm") / self.magnification


class RelayLensSpec(SpecModel):
    """The Fourier lens of a Fourier LFM, one focal length behind the native image plane.

    With the tube lens it forms a 4f relay that images the objective's back pupil onto
    its back focal plane, where the MLA sits (see :class:`~lfm_studio.engine.design.Design`).

    Attributes
    ----------
    focal_length_mm : float
        Focal length in mm (> 0).
    field_stop_diameter_mm : float or None
        Diameter in mm of an iris at the native image plane (the field stop that keeps
        the lenslets' sub-images apart); None when there is none.
    """

    focal_length_mm: float
    field_stop_diameter_mm: float | None = None

    @model_validator(mode="after")
    def _check(self) -> RelayLensSpec:
        require_positive("focal_length_mm", self.focal_length_mm, "mm", "e.g. 75 for a 75 mm Fourier lens.")
        if self.field_stop_diameter_mm is not None:
            require_positive(
                "field_stop_diameter_mm",
                self.field_stop_diameter_mm,
                "mm",
                "give the iris diameter, or leave it out.",
            )
        return self

    @property
    def focal_length(self) -> float:
        """Focal length in metres."""
        return si(self.focal_length_mm, "mm")

    @property
    def field_stop_diameter(self) -> float | None:
        """Field-stop diameter at the native image plane in metres (None if there is none)."""
        return None if self.field_stop_diameter_mm is None else si(self.field_stop_diameter_mm, "mm")
