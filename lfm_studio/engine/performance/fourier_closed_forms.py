"""Closed-form metrics of a Fourier LFM (FLFM, XLFM): MLA on the relayed objective pupil.

Notation (SI): objective magnification ``M``, numerical aperture ``NA``, immersion
index ``n``; Fourier (relay) lens ``f_F``; MLA-to-camera distance ``d``; camera pixel
``delta``; wavelength ``lambda``; lenslet ``i`` with aperture ``D_i`` (diameter, or
side of a square) centred at radius ``r_i`` from the axis on the MLA.

- Pupil on the MLA: diameter ``D_P = 2 NA f_F / M`` (Guo et al. 2019, Opt. Express 27,
  25573, section 2; :attr:`Design.pupil_diameter_at_mla`). A lenslet is a **view**
  when its centre lies inside that disc; ``N = D_P / D`` views fit across it.
- Magnification ``M_T = M d / f_F`` (Guo 2019 writes ``f_MLA`` for ``d``: the camera at
  the lenslets' focal plane).
- Effective NA of one view: the lenslet passes the fraction ``D / D_P`` of the pupil
  diameter, so ``NA_eff = NA D / D_P = D M / (2 f_F)`` (Guo 2019; Scrofani et al. 2018,
  Biomed. Opt. Express 9, 335, "FIMic"; Galdon et al. 2022, Appl. Opt., doi:10.1364/AO.453723).
- Lateral resolution ``max(c lambda / NA_eff, 2 delta / M_T)``: the diffraction limit
  of one view by the chosen criterion (``c`` = 0.61 Rayleigh, the default as in the
  thesis section 3.3.1; 0.5 Abbe, as Guo 2019 and Scrofani 2018 report it; 0.47
  Sparrow), or two sensor pixels (Nyquist) projected to the sample, whichever is
  coarser (``lateral_resolution_limit`` names which; the criterion cannot change the
  pixel limit). The largest lenslet among the views is used.
- Axial resolution, thesis eq. 3.24 with the immersion index (the engine's derivation,
  checked on the simulated PSF in ``tests/engine/systems/test_fourier_psf.py``): a
  depth step ``dz`` moves the spot of view ``i`` radially by ``d r_i M^2 dz / (n f_F^2)``
  on the sensor; it is resolved when that equals the Rayleigh radius
  ``1.22 lambda d / D_i`` of the lenslet's spot:
  ``dz_i = 1.22 lambda n f_F^2 / (D_i r_i M^2)``. Paraxial (``sin theta ~ tan theta``):
  for the outermost view of the XLFM preset (``sin theta = 0.52``) the exact parallax
  ``tan(theta)`` is 17 % larger, so eq. 3.24 is that much pessimistic there.
  Reported: the best view (largest ``D_i r_i``) and the mean over views off the axis.
- Depth of field of one view: the classical microscope depth of field (Inoue & Spring,
  "Video Microscopy", 1997; used with ``NA_eff`` by Scrofani 2018 and Guo 2019)
  ``lambda n / NA_eff^2 + n delta / (M_T NA_eff)``, centred where the view is in focus.
  A source at depth ``z`` reaches the MLA as a wave of converging power
  ``z M^2 / (n f_F^2)``; with a lenslet of focal length ``f`` it focuses at ``d`` for
  ``z_f = n f_F^2 (1/d - 1/f) / M^2`` (0 when ``d = f``). Multifocal arrays (XLFM:
  two groups) cover the union of their groups' intervals; the reported
  depth of field is the total length of that union, ``depth_range`` its extent.
- Field of view: the tightest of the objective field number (``FN / M``), the field stop
  at the native image plane (``FS / M``), the nearest-neighbour spacing of the views on
  the sensor (``s / M_T``: sub-images wider than the lenslet spacing overlap; Guo 2019
  ``FOV = d_MLA / M_T``), and the short side of the sensor (``/ M_T``).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from typing import NoReturn

from lfm_studio.engine.design import Design, LensletSpec, RelayLensSpec
from lfm_studio.engine.systems.closed_form_record import (
    ClosedFormMetrics,
    criterion_factor,
    lateral_limit_label,
    tightest_limit,
)
from lfm_studio.engine.systems.kinds import FOURIER, kind_of

PIXEL_SAMPLING = "Nyquist 2 pixels/M_T"
"""Label of the Fourier LFM's sampling limit, two sensor pixels projected to the sample."""

RAYLEIGH = 1.22
"""Rayleigh factor of a circular aperture: first Airy zero at ``1.22 lambda / (2 NA)``."""


def _no_relay(design: Design) -> NoReturn:
    raise ValueError(
        f"Fourier closed forms need a relay (Fourier) lens; design {design.name!r} (kind {design.kind!r}) "
        "has relay None. Fix: use conventional_closed_forms, or add relay={'focal_length_mm': ...}."
    )


def relay_of(design: Design) -> RelayLensSpec:
    """The relay (Fourier) lens of a Fourier design; ``ValueError`` for a design without one."""
    if design.relay is None:
        _no_relay(design)
    return design.relay


def pupil_diameter_of(design: Design) -> float:
    """Diameter of the pupil image on the MLA, m (:attr:`Design.pupil_diameter_at_mla` of a Fourier design)."""
    diameter = design.pupil_diameter_at_mla
    if diameter is None:
        _no_relay(design)
    return diameter


def views(design: Design) -> tuple[LensletSpec, ...]:
    """Lenslets whose centre lies inside the pupil image on the MLA (each records one view)."""
    radius = pupil_diameter_of(design) / 2.0
    return tuple(lens for lens in design.mla.lenslets if math.hypot(*lens.center) < radius)


def focus_depth(design: Design, focal_length: float) -> float:
    """Depth (m) that a lenslet of ``focal_length`` (m) focuses onto the camera (paraxial)."""
    objective = design.objective
    scale = objective.immersion_index * relay_of(design).focal_length ** 2 / objective.magnification**2
    return scale * (1.0 / design.mla_to_camera_distance - 1.0 / focal_length)


def axial_resolution_of(design: Design, lens: LensletSpec) -> float | None:
    """Thesis eq. 3.24 with the immersion index for one view, m (None on the axis)."""
    r = math.hypot(*lens.center)
    if r == 0.0:
        return None
    objective = design.objective
    return (
        RAYLEIGH
        * design.wavelength
        * objective.immersion_index
        * relay_of(design).focal_length ** 2
        / (lens.aperture_diameter * r * objective.magnification**2)
    )


def view_depth_of_field(design: Design, effective_na: float) -> float:
    """Inoue's depth of field ``lambda n / NA^2 + n delta / (M_T NA)`` of one view, m."""
    n = design.objective.immersion_index
    return design.wavelength * n / effective_na**2 + n * design.camera.pixel_pitch / (
        design.magnification * effective_na
    )


def union_length(intervals: list[tuple[float, float]]) -> float:
    """Total length covered by possibly overlapping intervals ``(lo, hi)``."""
    total, end = 0.0, -math.inf
    for lo, hi in sorted(intervals):
        if hi <= end:
            continue
        total += hi - max(lo, end)
        end = hi
    return total


def nearest_spacing(lenslets: tuple[LensletSpec, ...]) -> float | None:
    """Smallest centre-to-centre distance between lenslets, m (None for fewer than two)."""
    centres = [lens.center for lens in lenslets]
    best = math.inf
    for i in range(len(centres)):
        for j in range(i + 1, len(centres)):
            best = min(best, math.dist(centres[i], centres[j]))
    return None if math.isinf(best) else best


def fourier_closed_forms(design: Design, *, criterion: str = "rayleigh") -> ClosedFormMetrics:
    """Closed-form metrics of a Fourier LFM design (see the module docstring for each formula);
    the lateral diffraction limit by ``criterion`` ("rayleigh", "abbe" or "sparrow")."""
    factor = criterion_factor(criterion)
    if kind_of(design) is not FOURIER:
        raise ValueError(
            f"fourier_closed_forms needs a Fourier-LFM design; got a {kind_of(design).title} ({design.kind!r}). "
            "Fix: use closed_form_metrics(design), which picks the formulas of its kind."
        )
    objective, camera = design.objective, design.camera
    m_t = design.magnification
    pupil, field_stop = pupil_diameter_of(design), relay_of(design).field_stop_diameter
    seen = views(design)
    notes = ["axial resolution: thesis eq. 3.24 with the immersion index (paraxial parallax)."]
    sampling = 2.0 * camera.pixel_pitch / m_t
    fov_limits: dict[str, float | None] = {
        "field number": objective.field_of_view_diameter,
        "field stop": None if field_stop is None else field_stop / objective.magnification,
        "sensor": min(camera.sensor_size) / m_t,
    }
    if not seen:
        notes.append("no lenslet centre lies inside the pupil image: the design records no view.")
        fov, fov_limit = tightest_limit(fov_limits)
        return ClosedFormMetrics(
            m_t, camera.pixel_pitch / m_t, objective.numerical_aperture, None, 0, 0.0,
            None, None, sampling, None, None, 0.0, (0.0, 0.0), fov, fov_limit, criterion, tuple(notes),
        )  # fmt: skip
    largest = max(lens.aperture_diameter for lens in seen)
    na_eff = objective.numerical_aperture * largest / pupil
    diffraction = factor * design.wavelength / na_eff
    axial = [a for a in (axial_resolution_of(design, lens) for lens in seen) if a is not None]
    if not axial:
        notes.append("no view lies off the axis: no parallax, so no axial resolution.")
    intervals = []
    for f in sorted({lens.focal_length for lens in seen}):
        group = max(lens.aperture_diameter for lens in seen if lens.focal_length == f)
        group_na = objective.numerical_aperture * group / pupil
        centre, half = focus_depth(design, f), view_depth_of_field(design, group_na) / 2.0
        intervals.append((centre - half, centre + half))
    if len(intervals) > 1:
        notes.append(f"{len(intervals)} lenslet focal lengths: depth of field is the union of their ranges.")
    spacing = nearest_spacing(seen)
    fov_limits["lenslet spacing"] = None if spacing is None else spacing / m_t
    fov, fov_limit = tightest_limit(fov_limits)
    return ClosedFormMetrics(
        magnification=m_t,
        sample_pixel_size=camera.pixel_pitch / m_t,
        numerical_aperture=objective.numerical_aperture,
        effective_numerical_aperture=na_eff,
        number_of_views=len(seen),
        views_across=pupil / largest,
        lateral_resolution=max(diffraction, sampling),
        lateral_resolution_diffraction=diffraction,
        lateral_resolution_sampling=sampling,
        axial_resolution=min(axial) if axial else None,
        axial_resolution_mean=sum(axial) / len(axial) if axial else None,
        depth_of_field=union_length(intervals),
        depth_range=(min(lo for lo, _ in intervals), max(hi for _, hi in intervals)),
        field_of_view=fov,
        field_of_view_limit=fov_limit,
        lateral_criterion=criterion,
        notes=tuple(notes),
        lateral_resolution_limit=lateral_limit_label(diffraction, sampling, criterion, PIXEL_SAMPLING),
    )
