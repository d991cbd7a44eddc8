"""Imaging requirements and their pass/fail check with margins (thesis section 2.3.1).

The thesis sets the specification for whole-brain imaging of larval zebrafish from the
brain size (about 400 x 800 x 250 um^3) and the neuron soma diameter (3-7 um):

- field of view >= 800 um ("for the immobilized zebrafish brain imaging task, the
  minimum FoV is 800 um");
- depth of field >= 200 um ("the minimum DoF is 200 um for imaging a whole zebrafish brain");
- lateral resolution <= 3 um: "around 150 x 270 of 3 x 3 um^2 voxels are required ... to
  achieve the cellular-level resolution", and a 3 x 3 x 5 um^3 cell must be resolved
  (the thesis judges Cong 2017's 3.4 x 3.4 x 5 um^3 not cellular for all neurons);
- axial resolution <= 5 um: "at least 50 5 um thick slices".

Interpretation used here: a resolution (two-point distance) no larger than the cell
size along that axis. Requirements are data (:class:`Requirement`); other organisms
or tasks are new tuples of them.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from lfm_studio.engine import units

Comparison = Literal[">=", "<="]


@dataclass(frozen=True)
class Requirement:
    """One imaging requirement on a metric.

    Attributes
    ----------
    quantity : str
        Name of the metric it constrains (a field of the metrics, e.g. ``"field_of_view"``).
    comparison : ">=" or "<="
        ``value >= limit`` (at least) or ``value <= limit`` (at most).
    limit : float
        The limit in SI units (metres for lengths).
    reason : str
        Where the requirement comes from.
    unit : str
        Unit shown and saved for ``limit`` and values ("um" for lengths, "" unitless).
    """

    quantity: str
    comparison: Comparison
    limit: float
    reason: str
    unit: str = "um"

    def margin(self, value: float) -> float:
        """Signed margin in SI: >= 0 when ``value`` meets the requirement."""
        return value - self.limit if self.comparison == ">=" else self.limit - value


@dataclass(frozen=True)
class RequirementCheck:
    """The outcome of one requirement for one value.

    Attributes
    ----------
    quantity, comparison, limit : as in :class:`Requirement`.
    value : float or None
        The metric checked (SI); None when it is not defined for the design.
    basis : "closed_form" or "measured"
        Whether ``value`` is a closed form or was measured on a simulated PSF.
    passed : bool or None
        None when it cannot be told: ``value`` is None, or ``value`` is only a lower
        bound (a measured depth of field cut off by the PSF stack) that falls short.
    margin : float or None
        Signed margin in SI (``value - limit`` for ">=", ``limit - value`` for "<=").
    unit : str
        As in :class:`Requirement`.
    criterion : str
        How ``value`` was judged, when that matters (e.g. "Rayleigh 0.61 lambda/NA" for a
        closed-form lateral resolution, "two-point dip < 0.735" for a measured one); "" otherwise.
    """

    quantity: str
    comparison: Comparison
    limit: float
    value: float | None
    basis: str
    passed: bool | None
    margin: float | None
    unit: str = "um"
    criterion: str = ""

    @property
    def label(self) -> str:
        """The quantity with its criterion, e.g. "lateral_resolution (Rayleigh 0.61 lambda/NA)"."""
        return f"{self.quantity} ({self.criterion})" if self.criterion else self.quantity

    @property
    def relative_margin(self) -> float | None:
        """Margin as a fraction of the limit (e.g. 0.25 = 25 % to spare)."""
        return None if self.margin is None else self.margin / self.limit


ZEBRAFISH_LARVA: tuple[Requirement, ...] = (
    Requirement(
        "field_of_view", ">=", 800 * units.um, "thesis 2.3.1: minimum FoV 800 um (larval zebrafish brain)"
    ),
    Requirement(
        "depth_of_field", ">=", 200 * units.um, "thesis 2.3.1: minimum DoF 200 um (whole brain depth)"
    ),
    Requirement(
        "lateral_resolution", "<=", 3 * units.um, "thesis 2.3.1: 3 x 3 um lateral cells (150 x 270 voxels)"
    ),
    Requirement(
        "axial_resolution", "<=", 5 * units.um, "thesis 2.3.1: 5 um cells axially (50 slices of 5 um)"
    ),
)
"""Whole-brain imaging of a larval zebrafish (thesis section 2.3.1)."""


def check(
    requirement: Requirement,
    value: float | None,
    basis: str,
    *,
    lower_bound: bool = False,
    criterion: str = "",
) -> RequirementCheck:
    """Check one ``value`` (SI, or None when undefined) against ``requirement``.

    ``lower_bound=True``: the true value may be larger (e.g. a depth of field cut off by
    the end of a PSF stack), so a shortfall on an ">=" requirement is undecided (None).
    ``criterion`` names how ``value`` was judged (kept in the check).
    """
    req = requirement
    if value is None:
        return RequirementCheck(
            req.quantity, req.comparison, req.limit, None, basis, None, None, req.unit, criterion
        )
    margin = req.margin(value)
    passed: bool | None = margin >= 0.0
    if lower_bound and not passed and req.comparison == ">=":
        passed = None
    return RequirementCheck(
        req.quantity, req.comparison, req.limit, value, basis, passed, margin, req.unit, criterion
    )


def check_requirements(
    values: dict[str, float | None],
    requirements: tuple[Requirement, ...] = ZEBRAFISH_LARVA,
    *,
    basis: str = "closed_form",
    lower_bounds: frozenset[str] = frozenset(),
    criteria: dict[str, str] | None = None,
) -> tuple[RequirementCheck, ...]:
    """Check the metrics in ``values`` (quantity -> SI value) that ``requirements`` constrain.

    Requirements whose quantity is not a key of ``values`` are skipped (e.g. no
    measured field of view); quantities in ``lower_bounds`` are lower bounds (see :func:`check`);
    ``criteria`` maps a quantity to the criterion it was judged by.
    """
    criteria = criteria or {}
    return tuple(
        check(
            req, values[req.quantity], basis, lower_bound=req.quantity in lower_bounds,
            criterion=criteria.get(req.quantity, ""),
        )
        for req in requirements
        if req.quantity in values
    )  # fmt: skip


def overall(checks: tuple[RequirementCheck, ...]) -> bool | None:
    """False if any check failed, True if all passed, None if none failed but some are undecided."""
    outcomes = [c.passed for c in checks]
    if any(p is False for p in outcomes):
        return False
    return None if any(p is None for p in outcomes) else True
