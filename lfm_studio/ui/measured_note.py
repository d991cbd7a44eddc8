"""What the design-metrics panel says about measured (*) values, per system kind (Qt-free).

The PSF measures (FWHM, two-point resolution, depth of field:
:mod:`lfm_studio.engine.performance.psf_measures`) need one laterally shift-invariant PSF per
depth, which a Fourier LFM's stack holds. A conventional LFM's stack holds lenslet patterns
that change with the source position behind each lenslet, so the studio, like
``lfm-studio info --measure``, shows its formula estimates only, and says so instead of
promising measured values that never come.
"""

from __future__ import annotations

from typing import Any

from lfm_studio.engine.performance.psf_measures_stack import unmeasurable_reason
from lfm_studio.engine.systems.kinds import kind_of

MEASURED_LATER = "Bars: formula estimates, then measured on the PSF (*) once the full stack is in."
MEASURED_LATER_WHY = "Measured (*) values: FWHM, two-point resolution and depth of field of the PSF stack."


def measured_unavailable(subject: Any) -> str | None:
    """Why no measured values are shown for ``subject`` (a design, or its ``DesignMetrics``), in one
    short line, or None when they come with the full PSF stack."""
    if unmeasurable_reason(subject) is None:
        return None
    return (
        f"Bars: formula estimates only. A {kind_of(subject).title} gets no measured values (*): "
        "its PSF is not one shift-invariant PSF per depth."
    )


def measured_note(subject: Any) -> tuple[str, str]:
    """The panel's line on its bars for ``subject``'s kind (measured later, or why never) and its tooltip."""
    why = measured_unavailable(subject)
    if why is None:
        return MEASURED_LATER, MEASURED_LATER_WHY
    reason = str(unmeasurable_reason(subject))
    return why, (
        f"Measured (*) values: {reason[0].upper()}{reason[1:]}. As with lfm-studio info --measure, only the "
        "formula estimates (FWHM, two-point resolution, depth of field) are shown. For a measured "
        "resolution, run lfm-studio resolution on the design file (it reconstructs two points; minutes)."
    )
