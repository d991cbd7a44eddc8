"""Closed-form metrics of a conventional LFM (MLA on the native image plane), after Levoy 2006.

Notation (SI): objective magnification ``M``, numerical aperture ``NA``, immersion index
``n``; lenslet pitch ``p`` and MLA-to-camera distance ``d`` (the lenslet focal length);
camera pixel ``delta``; wavelength ``lambda``. Sources: M. Levoy, R. Ng, A. Adams,
M. Footer, M. Horowitz, "Light field microscopy", ACM Trans. Graph. 25, 924 (2006),
section 3 (Levoy 2006); M. Broxton et al., "Wave optics theory and 3-D deconvolution
for the light field microscope", Opt. Express 21, 25418 (2013) (Broxton 2013).

- Magnification: ``M`` onto the MLA (each lenslet is one spatial sample; the camera
  behind it records the pupil, i.e. directions).
- Views: each lenslet images the pupil onto a disc of diameter
  ``D_img = 2 d tan(asin(NA / M))`` (at most ``p``; :attr:`Design.sub_image_radius`).
  Resolvable spots in it: ``N_u = D_img / max(delta, 0.94 lambda d / p)`` (the larger of
  a pixel and the lenslet's Sparrow spot ``0.47 lambda / NA_lenslet``, ``NA_lenslet =
  p / (2 d)``); f-number matched this is Levoy's ``N_u = W / R_obj`` with
  ``R_obj = 0.47 lambda M / NA``. ``number_of_views`` counts the spots (views: the thesis
  forms one view from the same pixel behind every lenslet) over the part of the square
  lenslet the pupil image covers: area of disc ``D_img`` intersect square ``p``, over
  ``spot^2`` (``pi/4 N_u^2`` for a disc inside the lenslet, ``N_u^2`` only once the disc
  reaches the corners, ``D_img >= p sqrt(2)``; at most ``pi/4 N_u^2`` for round lenslets).
  The effective NA of one view is ``NA / N_u``.
- Lateral resolution: ``max(c lambda / NA, p / M)`` (``c`` of the chosen criterion:
  0.61 Rayleigh by default, 0.5 Abbe, 0.47 Sparrow): at the native focal plane the
  light field samples the sample once per lenslet (Levoy 2006: lateral resolution of
  focused images = lenslet pitch at the specimen). 3-D deconvolution recovers finer
  detail away from that plane (Broxton 2013), not reflected here. ``lateral_resolution_limit``
  names the term that sets it; the criterion cannot change the lenslet sampling limit.
- Axial resolution: the depth of field of a synthetically refocused image, Inoue's
  formula with the lenslet pitch as the "pixel" (Levoy 2006 eq. for ``D_tot``):
  ``lambda n / NA^2 + n p / (M NA)`` (about ``(2 + N_u) lambda n / (2 NA^2)``).
- Depth of field: ``N_u`` refocused slices with non-overlapping depths of field fit in
  the light field (a view step shifts the parallax by one lenslet), so
  ``DoF = max(N_u, 1) x axial resolution``, centred on the native focal plane.
- Field of view: the tightest of the field number (``FN / M``), the MLA extent (short
  side of its bounding box ``/ M``) and the sensor short side ``/ M``.
"""

from __future__ import annotations

import math

from lfm_studio.engine import units
from lfm_studio.engine.design import Design, RegularMLASpec
from lfm_studio.engine.systems.closed_form_record import (
    LATERAL_CRITERIA,
    ClosedFormMetrics,
    criterion_factor,
    lateral_limit_label,
    tightest_limit,
)
from lfm_studio.engine.systems.kinds import CONVENTIONAL, kind_of

LENSLET_SAMPLING = "lenslet sampling pitch/M"
"""Label of the conventional LFM's native-plane lateral limit, one sample per lenslet."""

SPARROW = LATERAL_CRITERIA["sparrow"]
"""Sparrow factor used by Levoy 2006: two points resolve at ``0.47 lambda / NA``."""


def lenslet_pitch(design: Design) -> float:
    """Lenslet pitch, m: the regular array's pitch, else the largest lenslet aperture."""
    mla = design.mla
    if isinstance(mla, RegularMLASpec):
        return mla.pitch_um * units.um
    return max(lens.aperture_diameter for lens in mla.lenslets)


def mla_extent(design: Design) -> float:
    """Short side of the bounding box of all lenslet apertures, m."""
    mla = design.mla
    if isinstance(mla, RegularMLASpec):
        centres = [(x * units.um, y * units.um) for x, y in mla.centers_um()]
        half = mla.lenslet_aperture_um * units.um / 2.0
    else:
        centres = [lens.center for lens in mla.lenslets]
        half = max(lens.aperture_diameter for lens in mla.lenslets) / 2.0
    xs, ys = [c[0] for c in centres], [c[1] for c in centres]
    return min(max(xs) - min(xs), max(ys) - min(ys)) + 2.0 * half


def lenslet_is_square(design: Design) -> bool:
    """Whether the lenslets are square (the regular array's shape, else the largest lenslet's)."""
    mla = design.mla
    if isinstance(mla, RegularMLASpec):
        return mla.lenslet_shape == "square"
    return max(mla.lenslets, key=lambda lens: lens.aperture_diameter).shape == "square"


def covered_lenslet_area(pupil_image: float, pitch: float, *, square: bool = True) -> float:
    """Area of a lenslet of side (``square``) or diameter ``pitch`` (m) covered by the centred
    pupil image, a disc of diameter ``pupil_image`` (m), m^2: for a square, the disc minus the
    four caps beyond the sides; for a round lenslet, the smaller disc."""
    r, a = pupil_image / 2.0, pitch / 2.0
    if r <= a or not square:
        r = min(r, a)
        return math.pi * r**2
    if r >= a * math.sqrt(2.0):
        return pitch**2
    cap = r**2 * math.acos(a / r) - a * math.sqrt(r**2 - a**2)  # one side cuts this off
    return math.pi * r**2 - 4.0 * cap


def conventional_closed_forms(design: Design, *, criterion: str = "rayleigh") -> ClosedFormMetrics:
    """Closed-form metrics of a conventional LFM design (see the module docstring); the lateral
    diffraction limit by ``criterion`` ("rayleigh", "abbe" or "sparrow")."""
    factor = criterion_factor(criterion)
    if kind_of(design) is not CONVENTIONAL:
        raise ValueError(
            f"conventional_closed_forms needs a conventional-LFM design; got a {kind_of(design).title} "
            f"({design.kind!r}). Fix: use closed_form_metrics(design), which picks the formulas of its kind."
        )
    objective, camera = design.objective, design.camera
    na, n, m = objective.numerical_aperture, objective.immersion_index, design.magnification
    p, d, lam = lenslet_pitch(design), design.mla_to_camera_distance, design.wavelength
    notes = [
        "conventional LFM: lateral resolution is the native-plane limit (lenslet pitch at the sample); "
        "3-D deconvolution does better away from the native focal plane (Broxton 2013).",
    ]
    sub_image_radius = design.sub_image_radius
    if sub_image_radius is None:  # only a Fourier design (relay, unlimited field) has none
        raise ValueError("conventional_closed_forms needs the sub-image radius; the design has none.")
    pupil_image = 2.0 * sub_image_radius
    spot = max(camera.pixel_pitch, 2.0 * SPARROW * lam * d / p)
    n_u = min(pupil_image, p) / spot
    views = math.floor(covered_lenslet_area(pupil_image, p, square=lenslet_is_square(design)) / spot**2)
    if n_u < 1.0:
        notes.append(
            f"fewer than one resolvable spot behind a lenslet (N_u = {n_u:.3g}): no angular sampling."
        )
    diffraction, sampling = factor * lam / na, p / m
    axial = lam * n / na**2 + n * p / (m * na)
    dof = max(n_u, 1.0) * axial
    fov, fov_limit = tightest_limit(
        {
            "field number": objective.field_of_view_diameter,
            "MLA extent": mla_extent(design) / m,
            "sensor": min(camera.sensor_size) / m,
        }
    )
    return ClosedFormMetrics(
        magnification=m,
        sample_pixel_size=camera.pixel_pitch / m,
        numerical_aperture=na,
        effective_numerical_aperture=na / n_u if n_u > 0 else None,
        number_of_views=views,
        views_across=n_u,
        lateral_resolution=max(diffraction, sampling),
        lateral_resolution_diffraction=diffraction,
        lateral_resolution_sampling=sampling,
        axial_resolution=axial,
        axial_resolution_mean=axial,
        depth_of_field=dof,
        depth_range=(-dof / 2.0, dof / 2.0),
        field_of_view=fov,
        field_of_view_limit=fov_limit,
        lateral_criterion=criterion,
        notes=tuple(notes),
        lateral_resolution_limit=lateral_limit_label(diffraction, sampling, criterion, LENSLET_SAMPLING),
    )
