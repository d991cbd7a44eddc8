"""The closed-form metrics record and its criteria, shared by both kinds' formulas (SI units).

:class:`ClosedFormMetrics` is what :mod:`lfm_studio.engine.performance.fourier_closed_forms` and
:mod:`lfm_studio.engine.performance.conventional_closed_forms` fill, and what a system kind's
:meth:`~lfm_studio.engine.systems.kinds_base.SystemKind.closed_forms` returns (so the record
sits here, beside the kinds, below the performance package that holds the formulas).
Lateral resolution criterion (:data:`LATERAL_CRITERIA`): the diffraction limit is
``c lambda / NA`` with ``c`` = 0.61 (Rayleigh, the default: the thesis, section
3.3.1, reads the zebrafish requirements of section 2.3.1 against it), 0.5 (Abbe,
``lambda / (2 NA)``) or 0.47 (Sparrow). The criterion is named in the metrics
(``lateral_criterion``), the JSON, ``lfm-studio info`` and the studio's requirement
table; docs/resolution_conventions.md compares every closed form with the thesis.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

LATERAL_CRITERIA: dict[str, float] = {"rayleigh": 0.61, "abbe": 0.5, "sparrow": 0.47}
"""Factor ``c`` of the lateral diffraction limit ``c lambda / NA`` per criterion (Born & Wolf
7.6.3: Rayleigh = first Airy zero 0.61; Abbe = lambda / (2 NA); Sparrow = 0.47, the dip just vanishes)."""

CRITERION_LABELS: dict[str, str] = {
    "rayleigh": "Rayleigh 0.61 lambda/NA",
    "abbe": "Abbe lambda/(2 NA)",
    "sparrow": "Sparrow 0.47 lambda/NA",
}
"""How each criterion is shown (tables, the studio)."""


def criterion_factor(criterion: str) -> float:
    """``c`` of ``c lambda / NA`` for ``criterion`` (ValueError naming the choices otherwise)."""
    if criterion not in LATERAL_CRITERIA:
        raise ValueError(
            f"criterion must be one of {sorted(LATERAL_CRITERIA)}; got {criterion!r}. "
            "Fix: 'rayleigh' (thesis 3.3.1), 'abbe' or 'sparrow'."
        )
    return LATERAL_CRITERIA[criterion]


SAME_FOR_EVERY_CRITERION = "same for every criterion"
"""Added to the label of a sampling-limited lateral resolution: the criterion cannot change it."""


def lateral_limit_label(diffraction: float, sampling: float, criterion: str, sampling_label: str) -> str:
    """What sets ``max(diffraction, sampling)`` (both m): the criterion's label
    (:data:`CRITERION_LABELS`) when the diffraction limit is the coarser, else ``sampling_label``
    (e.g. "lenslet sampling pitch/M") and that no criterion changes it."""
    if sampling > diffraction:
        return f"{sampling_label}, {SAME_FOR_EVERY_CRITERION}"
    return CRITERION_LABELS[criterion]


UM = {"unit": "um"}
"""Field metadata: a length shown and saved in micrometres (SI metres in the object)."""


@dataclass(frozen=True)
class ClosedFormMetrics:
    """Design metrics from closed-form expressions (lengths in metres, sample side).

    Attributes
    ----------
    magnification : float
        Lateral magnification sample -> sensor (``M_obj d / f_relay`` for a Fourier
        LFM, ``M_obj`` at the MLA for a conventional LFM).
    sample_pixel_size : float
        One sensor pixel projected into the sample, m.
    numerical_aperture : float
        Objective NA.
    effective_numerical_aperture : float or None
        NA of one view (the part of the pupil one lenslet or one pixel sees).
    number_of_views : int
        Perspective views recorded at once (lenslets that see the pupil, or pixels
        behind a lenslet that see it).
    views_across : float
        Views across the pupil diameter (``N`` of Guo 2019, ``N_u`` of Levoy 2006).
    lateral_resolution : float or None
        ``max(lateral_resolution_diffraction, lateral_resolution_sampling)``, m.
    lateral_resolution_diffraction, lateral_resolution_sampling : float or None
        The optical (diffraction) and the sampling (pixel or lenslet) limits, m.
    axial_resolution : float or None
        Best axial resolution (the view with the largest parallax), m; None when no view
        has parallax (a single on-axis lenslet).
    axial_resolution_mean : float or None
        Mean over the views with parallax, m.
    depth_of_field : float
        Total depth over which the lateral resolution holds, m (union over lenslet
        groups focused at different depths).
    depth_range : (float, float)
        Lowest and highest depth of that union, m (0 = native focal plane, + away
        from the objective).
    field_of_view : float or None
        Diameter of the imaged field at the sample, m (None: no limit known).
    field_of_view_limit : str
        Which limit sets ``field_of_view`` (e.g. "field stop", "lenslet spacing").
    lateral_criterion : "rayleigh", "abbe" or "sparrow"
        The criterion of ``lateral_resolution_diffraction`` (:data:`LATERAL_CRITERIA`).
    lateral_resolution_limit : str
        Which limit sets ``lateral_resolution`` (:func:`lateral_limit_label`): the criterion's
        label, or the sampling limit (e.g. "lenslet sampling pitch/M, same for every
        criterion"); "" when there is no lateral resolution (or in records written before it).
    notes : tuple of str
        Assumptions and caveats that apply to this design.
    """

    magnification: float
    sample_pixel_size: float = field(metadata=UM)
    numerical_aperture: float
    effective_numerical_aperture: float | None
    number_of_views: int
    views_across: float
    lateral_resolution: float | None = field(metadata=UM)
    lateral_resolution_diffraction: float | None = field(metadata=UM)
    lateral_resolution_sampling: float | None = field(metadata=UM)
    axial_resolution: float | None = field(metadata=UM)
    axial_resolution_mean: float | None = field(metadata=UM)
    depth_of_field: float = field(metadata=UM)
    depth_range: tuple[float, float] = field(metadata=UM)
    field_of_view: float | None = field(metadata=UM)
    field_of_view_limit: str
    lateral_criterion: str = "rayleigh"
    notes: tuple[str, ...] = ()
    lateral_resolution_limit: str = ""


def tightest_limit(limits: dict[str, float | None]) -> tuple[float | None, str]:
    """The smallest known limit and its name (``(None, "none")`` when none is known)."""
    known = {name: value for name, value in limits.items() if value is not None}
    if not known:
        return None, "none"
    name = min(known, key=known.__getitem__)
    return known[name], name
