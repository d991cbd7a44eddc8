"""One lenslet of a microlens array, and the geometry of its aperture.

Apertures are circles (``aperture_diameter_um`` is the diameter) or axis-aligned
squares (``aperture_diameter_um`` is the side). Centres are relative to the
optical axis, x to the right and y up the rows of the camera.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import model_validator

from lfm_studio.engine.design.base import SpecModel, si, si_pair
from lfm_studio.engine.design.errors import fmt, require_finite, require_positive

LensletShape = Literal["circle", "square"]


class LensletSpec(SpecModel):
    """A thin lens with its own aperture.

    Attributes
    ----------
    center_um : (x, y)
        Lens axis in micrometres from the optical axis.
    aperture_diameter_um : float
        Diameter (circle) or side (square) of the clear aperture, micrometres.
    focal_length_mm : float
        Focal length in millimetres (> 0, converging).
    shape : "circle" or "square"
        Aperture shape; squares are axis aligned.
    """

    center_um: tuple[float, float]
    aperture_diameter_um: float
    focal_length_mm: float
    shape: LensletShape = "circle"

    @model_validator(mode="after")
    def _check(self) -> LensletSpec:
        require_finite("center_um x", self.center_um[0], "um", "give the lenslet centre in micrometres.")
        require_finite("center_um y", self.center_um[1], "um", "give the lenslet centre in micrometres.")
        require_positive("aperture_diameter_um", self.aperture_diameter_um, "um", "e.g. 150.")
        require_positive("focal_length_mm", self.focal_length_mm, "mm", "give a converging lens, e.g. 3.")
        return self

    @property
    def center(self) -> tuple[float, float]:
        """Centre ``(x, y)`` in metres."""
        return si_pair(self.center_um, "um")

    @property
    def aperture_diameter(self) -> float:
        """Aperture diameter (or side) in metres."""
        return si(self.aperture_diameter_um, "um")

    @property
    def focal_length(self) -> float:
        """Focal length in metres."""
        return si(self.focal_length_mm, "mm")

    @property
    def numerical_aperture(self) -> float:
        """Paraxial image-side NA ``D / (2 f)`` (unitless; side of a square along x)."""
        return self.aperture_diameter / (2.0 * self.focal_length)

    @property
    def reach_um(self) -> float:
        """Largest distance from the optical axis to the aperture edge, micrometres."""
        x, y = self.center_um
        half = self.aperture_diameter_um / 2.0
        if self.shape == "circle":
            return math.hypot(x, y) + half
        return math.hypot(abs(x) + half, abs(y) + half)

    def describe(self, index: int) -> str:
        """``lenslet 3 (centre (150, 0) um)`` for messages."""
        x, y = self.center_um
        return f"lenslet {index} (centre ({fmt(x)}, {fmt(y)}) um)"


def overlap_depth_um(a: LensletSpec, b: LensletSpec) -> float:
    """How far the apertures of ``a`` and ``b`` interpenetrate, micrometres (<= 0: apart or touching)."""
    dx, dy = abs(a.center_um[0] - b.center_um[0]), abs(a.center_um[1] - b.center_um[1])
    ha, hb = a.aperture_diameter_um / 2.0, b.aperture_diameter_um / 2.0
    if a.shape == b.shape == "circle":
        return ha + hb - math.hypot(dx, dy)
    if a.shape == b.shape == "square":
        return min(ha + hb - dx, ha + hb - dy)
    radius, half = (ha, hb) if a.shape == "circle" else (hb, ha)
    ox, oy = dx - half, dy - half  # circle centre relative to the square's edges
    if ox <= 0.0 and oy <= 0.0:
        return radius - max(ox, oy)
    return radius - math.hypot(max(ox, 0.0), max(oy, 0.0))
