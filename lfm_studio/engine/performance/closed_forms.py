"""Closed-form design metrics of a light-field microscope (thesis section 2.3.1), SI units.

:func:`closed_form_metrics` asks the design's system kind
(:func:`~lfm_studio.engine.systems.kinds.kind_of`) for its closed forms
(:meth:`~lfm_studio.engine.systems.kinds_base.SystemKind.closed_forms`), which are
:mod:`.fourier_closed_forms` (MLA on the Fourier plane: FLFM, XLFM) or
:mod:`.conventional_closed_forms` (MLA on the native image plane). Both fill the same
:class:`ClosedFormMetrics`, so reports and requirement checks treat them alike; each
field's docstring says what it means, and the two modules say how it is computed,
from which source, under which assumptions.

Lateral resolution criterion (:data:`LATERAL_CRITERIA`): the diffraction limit is
``c lambda / NA`` with ``c`` = 0.61 (Rayleigh, the default: the thesis, section
3.3.1, reads the zebrafish requirements of section 2.3.1 against it), 0.5 (Abbe,
``lambda / (2 NA)``) or 0.47 (Sparrow). The criterion is named in the metrics
(``lateral_criterion``), the JSON, ``lfm-studio info`` and the studio's requirement
table; docs/resolution_conventions.md compares every closed form with the thesis.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

from collections.abc import Callable

from lfm_studio.engine.design import Design
from lfm_studio.engine.performance.conventional_closed_forms import conventional_closed_forms
from lfm_studio.engine.performance.fourier_closed_forms import fourier_closed_forms
from lfm_studio.engine.systems.closed_form_record import (
    CRITERION_LABELS,
    LATERAL_CRITERIA,
    UM,
    ClosedFormMetrics,
    criterion_factor,
    tightest_limit,
)
from lfm_studio.engine.systems.kinds import CONVENTIONAL, FOURIER, SystemKind, kind_of

__all__ = [
    "CLOSED_FORMS",
    "CRITERION_LABELS",
    "LATERAL_CRITERIA",
    "UM",
    "ClosedFormMetrics",
    "closed_form_metrics",
    "criterion_factor",
    "tightest_limit",
]


CLOSED_FORMS: dict[SystemKind, Callable[..., ClosedFormMetrics]] = {
    FOURIER: fourier_closed_forms,
    CONVENTIONAL: conventional_closed_forms,
}
"""The closed forms of each system kind, ``f(design, *, criterion) -> ClosedFormMetrics``: the
functions the kinds name in ``closed_forms_provider`` (a test checks they agree)."""


def closed_form_metrics(design: Design, *, criterion: str = "rayleigh") -> ClosedFormMetrics:
    """The closed-form metrics of ``design`` (Fourier or conventional LFM); lateral resolution
    by ``criterion`` ("rayleigh", "abbe" or "sparrow")."""
    criterion_factor(criterion)
    return kind_of(design).closed_forms(design, criterion=criterion)
