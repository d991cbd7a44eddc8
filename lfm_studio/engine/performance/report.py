"""The design-metrics report: closed forms, optional PSF measurements, requirement checks; JSON.

:class:`DesignMetrics` holds SI values. :meth:`DesignMetrics.to_dict` writes the units
people read, in the key names (``lateral_resolution_um``, ``wavelength_nm``), and
:meth:`DesignMetrics.from_dict` reads them back (a lossless round trip up to float
rounding of the unit conversion).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, fields
from typing import Any

from lfm_studio.engine import units
from lfm_studio.engine.design import Design
from lfm_studio.engine.performance.closed_forms import (
    CRITERION_LABELS,
    ClosedFormMetrics,
    closed_form_metrics,
)
from lfm_studio.engine.performance.psf_measures_report import MeasuredMetrics, measure_metrics
from lfm_studio.engine.performance.requirements import (
    ZEBRAFISH_LARVA,
    Requirement,
    RequirementCheck,
    check_requirements,
    overall,
)
from lfm_studio.engine.psf_stack import PSFStack

SCHEMA = "lfm_studio.design_metrics"
SCHEMA_VERSION = 2
"""2: the lateral resolution criterion is recorded (``closed_form.lateral_criterion``, each
check's ``criterion``). Version 1 records (always Abbe, ``lambda / (2 NA)``) still load."""
MEASURED_TWO_POINT_CRITERION = "two-point dip < 0.735"
"""How a measured (lateral or axial) two-point resolution is judged (:mod:`.two_point`)."""
UNIT_SCALE = {"um": units.um, "nm": units.nm, "mm": units.mm, "": 1.0}


def _key(name: str, unit: str) -> str:
    return f"{name}_{unit}" if unit else name


def _out(value: Any, unit: str) -> Any:
    """SI value -> file value in ``unit`` (None, numbers, tuples of numbers)."""
    if value is None or not unit:
        return list(value) if isinstance(value, tuple) else value
    if isinstance(value, tuple):
        return [v / UNIT_SCALE[unit] for v in value]
    return value / UNIT_SCALE[unit]


def _in(value: Any, unit: str) -> Any:
    """File value in ``unit`` -> SI (lists become tuples)."""
    if isinstance(value, list):
        return tuple(v * UNIT_SCALE[unit] if unit else v for v in value)
    if value is None or not unit or isinstance(value, bool):
        return value
    return value * UNIT_SCALE[unit]


def record_to_dict(record: Any) -> dict[str, Any]:
    """A metrics dataclass as a dict: unit-suffixed keys (field metadata ``unit``), file units."""
    return {
        _key(f.name, f.metadata.get("unit", "")): _out(getattr(record, f.name), f.metadata.get("unit", ""))
        for f in fields(record)
    }


def record_from_dict(cls: type, data: dict[str, Any]) -> Any:
    """Inverse of :func:`record_to_dict` for the dataclass ``cls``."""
    values = {}
    for f in fields(cls):
        unit = f.metadata.get("unit", "")
        key = _key(f.name, unit)
        if key in data:
            values[f.name] = _in(data[key], unit)
    return cls(**values)


def _check_to_dict(c: RequirementCheck) -> dict[str, Any]:
    u = c.unit
    relative = c.relative_margin
    return {
        "quantity": c.quantity,
        "comparison": c.comparison,
        _key("limit", u): _out(c.limit, u),
        _key("value", u): _out(c.value, u),
        "basis": c.basis,
        "passed": c.passed,
        _key("margin", u): _out(c.margin, u),
        "relative_margin": relative,
        "unit": u,
        "criterion": c.criterion,
    }


def _check_from_dict(d: dict[str, Any]) -> RequirementCheck:
    u = d.get("unit", "")
    return RequirementCheck(
        d["quantity"], d["comparison"], _in(d[_key("limit", u)], u), _in(d[_key("value", u)], u),
        d["basis"], d["passed"], _in(d[_key("margin", u)], u), u, d.get("criterion", ""),
    )  # fmt: skip


@dataclass(frozen=True)
class DesignMetrics:
    """Metrics of one design (SI units) and how they meet a set of requirements.

    Attributes
    ----------
    design_name : str
    kind : str
        The design-file word of the design's system kind (``design.kind``), as stored in the JSON.
    wavelength : float
        Emission wavelength, m.
    closed_form : ClosedFormMetrics
    measured : MeasuredMetrics or None
        Present when a PSF stack was given.
    requirements : tuple of RequirementCheck
        Closed-form checks, then measured ones (lateral and axial resolution from the
        two-point tests, depth of field) when ``measured`` is present.
    requirement_set : str
        Name of the requirements checked.
    """

    design_name: str
    kind: str
    wavelength: float
    closed_form: ClosedFormMetrics
    measured: MeasuredMetrics | None = None
    requirements: tuple[RequirementCheck, ...] = ()
    requirement_set: str = "larval zebrafish (thesis 2.3.1)"

    @property
    def requirements_met(self) -> bool | None:
        """False if any requirement fails, True if all pass, None if some cannot be decided."""
        return overall(self.requirements)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict with units in key names (``..._um``, ``wavelength_nm``)."""
        return {
            "schema": SCHEMA,
            "schema_version": SCHEMA_VERSION,
            "design_name": self.design_name,
            "kind": self.kind,
            "wavelength_nm": self.wavelength / units.nm,
            "closed_form": record_to_dict(self.closed_form),
            "measured": None if self.measured is None else record_to_dict(self.measured),
            "requirement_set": self.requirement_set,
            "requirements": [_check_to_dict(c) for c in self.requirements],
            "requirements_met": self.requirements_met,
        }

    def to_json(self, *, indent: int | None = 2) -> str:
        """:meth:`to_dict` as JSON text."""
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> DesignMetrics:
        """Read :meth:`to_dict` output back (``ValueError`` for another schema or version)."""
        if data.get("schema") != SCHEMA or data.get("schema_version") not in (1, SCHEMA_VERSION):
            raise ValueError(
                f"not a design-metrics record of schema {SCHEMA!r} version 1 or {SCHEMA_VERSION}; got "
                f"{data.get('schema')!r} version {data.get('schema_version')!r}."
            )
        measured = data.get("measured")
        closed = data["closed_form"]
        if data["schema_version"] == 1:  # written before the criterion was recorded: always Abbe
            closed = {"lateral_criterion": "abbe", **closed}
        return cls(
            design_name=data["design_name"],
            kind=data["kind"],
            wavelength=data["wavelength_nm"] * units.nm,
            closed_form=record_from_dict(ClosedFormMetrics, closed),
            measured=None if measured is None else record_from_dict(MeasuredMetrics, measured),
            requirements=tuple(_check_from_dict(d) for d in data["requirements"]),
            requirement_set=data.get("requirement_set", ""),
        )

    @classmethod
    def from_json(cls, text: str) -> DesignMetrics:
        """Read :meth:`to_json` output back."""
        return cls.from_dict(json.loads(text))


def compute_design_metrics(
    design: Design,
    *,
    psf: PSFStack | None = None,
    focus_depth: float | None = None,
    requirements: tuple[Requirement, ...] = ZEBRAFISH_LARVA,
    requirement_set: str = "larval zebrafish (thesis 2.3.1)",
    criterion: str = "rayleigh",
) -> DesignMetrics:
    """Closed-form metrics of ``design``, PSF measurements when ``psf`` is given, requirement checks.

    Parameters
    ----------
    design : the design.
    psf : a PSF stack ``(Z, Y, X)`` of the design (simulated or measured); None: closed forms only.
    focus_depth : reference depth of the measurements, m (default: the stack's sharpest slice).
    requirements : what to check (default: larval zebrafish, thesis section 2.3.1).
    requirement_set : name of ``requirements`` for the report.
    criterion : lateral resolution criterion of the closed forms: "rayleigh" (0.61 lambda / NA,
        thesis 3.3.1; default), "abbe" (lambda / (2 NA)) or "sparrow" (0.47 lambda / NA).
    """
    closed = closed_form_metrics(design, criterion=criterion)
    checks = check_requirements(
        {
            "field_of_view": closed.field_of_view,
            "depth_of_field": closed.depth_of_field,
            "lateral_resolution": closed.lateral_resolution,
            "axial_resolution": closed.axial_resolution,
        },
        requirements,
        criteria={"lateral_resolution": closed.lateral_resolution_limit or CRITERION_LABELS[criterion]},
    )
    measured = None
    if psf is not None:
        measured = measure_metrics(psf, focus_depth=focus_depth)
        checks += check_requirements(
            {
                "depth_of_field": measured.depth_of_field,
                "lateral_resolution": measured.lateral_two_point,
                "axial_resolution": measured.axial_two_point,
            },
            requirements,
            basis="measured",
            criteria={
                "lateral_resolution": MEASURED_TWO_POINT_CRITERION,
                "axial_resolution": MEASURED_TWO_POINT_CRITERION,
            },
            lower_bounds=frozenset({"depth_of_field"}) if measured.depth_of_field_truncated else frozenset(),
        )
    return DesignMetrics(
        design.name, design.kind, design.wavelength, closed, measured, checks, requirement_set
    )
