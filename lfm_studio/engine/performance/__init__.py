"""Design performance metrics of a light-field microscope (thesis section 2.3.1): what a design can resolve.

Closed forms (:func:`closed_form_metrics`: magnification, views, lateral and axial
resolution incl. thesis eq. 3.24, depth of field, field of view), measurements on a
PSF stack (:func:`measure_metrics`: lateral FWHM, axial correlation width, two-point
tests, depth of field), requirement checks (:data:`ZEBRAFISH_LARVA`: FoV >= 800 um,
DoF >= 200 um, 3 x 3 x 5 um cells) and the report :class:`DesignMetrics` with JSON
(units in key names), built by :func:`compute_design_metrics`. All values are SI.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from lfm_studio.engine.performance.closed_forms import ClosedFormMetrics, closed_form_metrics
from lfm_studio.engine.performance.psf_measures import (
    MeasuredDepthOfField,
    axial_fwhm,
    best_focus_index,
    lateral_fwhm,
    measured_depth_of_field,
)
from lfm_studio.engine.performance.psf_measures_report import MeasuredMetrics, measure_metrics
from lfm_studio.engine.performance.psf_measures_stack import measurement_depths, measurement_psf
from lfm_studio.engine.performance.report import DesignMetrics, compute_design_metrics
from lfm_studio.engine.performance.requirements import (
    ZEBRAFISH_LARVA,
    Requirement,
    RequirementCheck,
    check_requirements,
)
from lfm_studio.engine.performance.table import format_metrics_table
from lfm_studio.engine.performance.two_point import RAYLEIGH_DIP, two_point_axial, two_point_lateral

__all__ = [
    "RAYLEIGH_DIP",
    "ZEBRAFISH_LARVA",
    "ClosedFormMetrics",
    "DesignMetrics",
    "MeasuredDepthOfField",
    "MeasuredMetrics",
    "Requirement",
    "RequirementCheck",
    "axial_fwhm",
    "best_focus_index",
    "check_requirements",
    "closed_form_metrics",
    "compute_design_metrics",
    "format_metrics_table",
    "lateral_fwhm",
    "measure_metrics",
    "measured_depth_of_field",
    "measurement_depths",
    "measurement_psf",
    "two_point_axial",
    "two_point_lateral",
]
