"""All metrics measured on one PSF stack, as one frozen record (see :mod:`.psf_measures`, :mod:`.two_point`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from lfm_studio.engine.performance.psf_measures import (
    DOF_CRITERION,
    axial_fwhm,
    depth_index,
    lateral_fwhm,
    measured_depth_of_field,
)
from lfm_studio.engine.performance.two_point import RAYLEIGH_DIP, two_point_axial, two_point_lateral
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.systems.closed_form_record import UM


@dataclass(frozen=True)
class MeasuredMetrics:
    """Metrics read from a PSF stack (lengths in metres, sample side; None: not measurable).

    Attributes
    ----------
    focus_depth : float
        Depth of the reference slice (the sharpest, unless chosen), m; the lateral and
        axial measurements refer to it.
    lateral_fwhm, axial_fwhm : float or None
        Spot FWHM (mean of x and y) and width of the correlation-versus-depth curve, m.
    lateral_two_point, axial_two_point : float or None
        Smallest separations resolved with the dip criterion (0.735, Rayleigh-like), m.
    depth_of_field : float or None
        Depth over which the lateral FWHM stays within sqrt(2) of its best, m.
    depth_range : (float, float) or None
        Extent of that depth range, m.
    depth_of_field_truncated : bool
        The range reaches an end of the stack: ``depth_of_field`` is a lower bound.
    stack_depths : (float, float)
        First and last depth of the stack, m.
    depth_count : int
        Number of slices in the stack.
    """

    focus_depth: float = field(metadata=UM)
    lateral_fwhm: float | None = field(metadata=UM)
    lateral_two_point: float | None = field(metadata=UM)
    axial_fwhm: float | None = field(metadata=UM)
    axial_two_point: float | None = field(metadata=UM)
    depth_of_field: float | None = field(metadata=UM)
    depth_range: tuple[float, float] | None = field(metadata=UM)
    depth_of_field_truncated: bool
    stack_depths: tuple[float, float] = field(metadata=UM)
    depth_count: int


def measure_metrics(
    psf: PSFStack,
    *,
    focus_depth: float | None = None,
    threshold: float = RAYLEIGH_DIP,
    dof_criterion: float = DOF_CRITERION,
) -> MeasuredMetrics:
    """Measure every metric of :class:`MeasuredMetrics` on ``psf`` (data ``(Z, Y, X)``).

    The lateral and axial values refer to the slice nearest ``focus_depth`` (m; default:
    the sharpest slice, :func:`best_focus_index`); the axial ones need slices on both
    sides of it (the correlation width) or on one side (two-point) closer than one
    axial resolution.
    """
    focus = psf.depths[depth_index(psf, focus_depth)]
    dof = measured_depth_of_field(psf, criterion=dof_criterion)
    return MeasuredMetrics(
        focus_depth=focus,
        lateral_fwhm=lateral_fwhm(psf, depth=focus),
        lateral_two_point=two_point_lateral(psf, depth=focus, threshold=threshold),
        axial_fwhm=axial_fwhm(psf, depth=focus),
        axial_two_point=two_point_axial(psf, depth=focus, threshold=threshold),
        depth_of_field=None if dof is None else dof.depth_of_field,
        depth_range=None if dof is None else dof.depth_range,
        depth_of_field_truncated=False if dof is None else dof.truncated,
        stack_depths=(min(psf.depths), max(psf.depths)),
        depth_count=len(psf.depths),
    )
