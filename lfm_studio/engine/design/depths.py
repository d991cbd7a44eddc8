"""The source depths a PSF stack is computed at.

Depth ``z`` is measured from the native focal plane AWAY from the objective
(deeper into the sample), as in :mod:`lfm_studio.engine.optics.objective` and
:class:`~lfm_studio.engine.psf_stack.PSFStack`.
"""

from __future__ import annotations

import math

from pydantic import model_validator

from lfm_studio.engine.design.base import SpecModel, si
from lfm_studio.engine.design.errors import DesignError, fmt, require_finite, require_positive

MAX_DEPTHS = 4096  # more is almost surely a unit slip (step in nm instead of um)


class DepthSpec(SpecModel):
    """Evenly spaced depths ``start, start + step, ...`` up to and including ``stop``.

    Attributes
    ----------
    depth_range_um : (start, stop)
        First and last depth in micrometres, ``start <= stop`` (equal: one depth).
    depth_step_um : float
        Spacing in micrometres (> 0). ``stop`` is included when it lies on the grid
        (within 1e-9 of a step); otherwise the last depth is the one below it.
    """

    depth_range_um: tuple[float, float]
    depth_step_um: float

    @model_validator(mode="after")
    def _check(self) -> DepthSpec:
        start, stop = self.depth_range_um
        require_finite("depth_range_um start", start, "um", "e.g. -50.")
        require_finite("depth_range_um stop", stop, "um", "e.g. 50.")
        require_positive("depth_step_um", self.depth_step_um, "um", "e.g. 2.")
        if start > stop:
            raise DesignError(
                f"depth_range_um must be ordered (start <= stop); got ({fmt(start)}, {fmt(stop)}) um. "
                f"Fix: write ({fmt(stop)}, {fmt(start)})."
            )
        if self.count > MAX_DEPTHS:
            raise DesignError(
                f"depth_range_um ({fmt(start)}, {fmt(stop)}) um with depth_step_um {fmt(self.depth_step_um)} um "
                f"gives {self.count} depths, more than {MAX_DEPTHS}. Fix: use a larger step (micrometres)."
            )
        return self

    @property
    def count(self) -> int:
        """Number of depths."""
        start, stop = self.depth_range_um
        return math.floor((stop - start) / self.depth_step_um + 1e-9) + 1

    @property
    def values_um(self) -> tuple[float, ...]:
        """Depths in micrometres, ascending."""
        start = self.depth_range_um[0]
        return tuple(start + i * self.depth_step_um for i in range(self.count))

    @property
    def values(self) -> tuple[float, ...]:
        """Depths in metres, ascending (what :class:`~lfm_studio.engine.psf_stack.PSFStack` takes)."""
        return tuple(si(z, "um") for z in self.values_um)
