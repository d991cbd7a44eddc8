"""Physics checks of a whole design (the parts check themselves).

Geometry and assumptions (paraxial first-order optics, thin lenses, aberration free):

Fourier LFM (``kind="fourier"``). Objective (focal length ``f_obj = f_tube / M``) and
tube lens ``f_tube`` form the native image plane (NIP); the relay (Fourier) lens
``f_relay`` sits one focal length behind the NIP, and the MLA on its back focal plane.
Assuming the objective's back focal plane lies at the tube lens's front focal plane
(a telecentric 4f pair), tube and relay lens image the back pupil (diameter
``2 NA f_obj``, Abbe sine condition) onto the MLA with magnification ``f_relay / f_tube``::

    D_pupil(MLA) = 2 NA f_obj f_relay / f_tube = 2 NA f_relay / M

A point on the NIP at height ``h`` leaves the relay as a plane wave tilted by
``h / f_relay``; lenslet ``i`` focuses it at ``c_i + d h / f_relay`` on a camera a
distance ``d`` behind the MLA (``d`` = ``mla_to_camera_distance``). So each
sub-image is centred on its lenslet's axis ``c_i`` and a field of diameter ``F`` at
the NIP (``F`` = the smaller of the field stop and the objective's field number)
covers a disc of radius ``d F / (2 f_relay)`` on the sensor.

Conventional LFM (``kind="conventional"``). The MLA sits on the NIP, the camera a
distance ``d`` (usually the lenslet focal length) behind it. Image space of a 4f
microscope is telecentric, so the chief ray through a lenslet's centre is parallel
to the axis and each lenslet's sub-image (an image of the back pupil) is centred on
its axis with radius ``d tan(theta')``, ``sin(theta') = NA / M`` (image side, in air).
Sub-images tile without overlap when the lenslet f-number ``d / pitch`` is at least
the image-side f-number ``M / (2 NA)`` ("f-number matching").

Decisions: lenslets outside the pupil image and sub-images centred off the sensor
are errors (no light or no data for that lenslet); lenslets partly outside the pupil,
sub-images clipped by the sensor edge or overlapping each other, and undersampling
are :class:`DesignWarning` (the design is computable, but probably not what you want).
Overlaps shallower than half a camera pixel are ignored (the sensor cannot see them).
"""

from __future__ import annotations

import math
from typing import Protocol

from lfm_studio.engine.design.camera import CameraSpec
from lfm_studio.engine.design.errors import DesignError, fmt, warn_design
from lfm_studio.engine.design.geometry import disc_overlaps, list_pairs
from lfm_studio.engine.design.mla import AnyMLASpec, RegularMLASpec
from lfm_studio.engine.design.objective import ObjectiveSpec, RelayLensSpec
from lfm_studio.engine.design.pupil_phase import PupilPhaseSpec
from lfm_studio.engine.optics.zernike import noll_to_nm


class Design(Protocol):
    """What the checks read of a :class:`~lfm_studio.engine.design.design.Design` (its fields and
    derived lengths), so this module does not import the class that calls it (no import cycle)."""

    @property
    def kind(self) -> str: ...
    @property
    def wavelength_nm(self) -> float: ...
    @property
    def objective(self) -> ObjectiveSpec: ...
    @property
    def relay(self) -> RelayLensSpec | None: ...
    @property
    def pupil_phase(self) -> PupilPhaseSpec | None: ...
    @property
    def mla(self) -> AnyMLASpec: ...
    @property
    def mla_to_camera_distance_mm(self) -> float: ...
    @property
    def camera(self) -> CameraSpec: ...
    @property
    def pupil_diameter_at_mla(self) -> float | None: ...
    @property
    def sub_image_radius(self) -> float | None: ...


MIN_PIXELS_PER_SUB_IMAGE = 3  # fewer pixels across a conventional sub-image: no angular information


def check_design(design: Design) -> None:
    """Run every design-level check; raise :class:`DesignError` or warn :class:`DesignWarning`."""
    if design.kind == "fourier":
        if design.relay is None:
            raise DesignError(
                "kind 'fourier' needs a relay (the Fourier lens between the native image plane and the MLA); "
                "got relay None. Fix: add relay={'focal_length_mm': ...}, or use kind 'conventional'."
            )
        _check_pupil(design)
        _check_fourier_sub_images(design)
        _check_lenslet_nyquist(design)
    else:
        if design.relay is not None:
            raise DesignError(
                f"kind 'conventional' puts the MLA on the native image plane and uses no relay lens; got relay "
                f"focal_length_mm {fmt(design.relay.focal_length_mm)}. Fix: set relay to None, or use kind 'fourier'."
            )
        if design.pupil_phase is not None:
            _check_conventional_pupil_phase(design.pupil_phase)
        _check_conventional_sub_images(design)


def _check_conventional_pupil_phase(pupil_phase: PupilPhaseSpec) -> None:
    """A conventional design's mask may hold rotationally symmetric (``m = 0``) terms only."""
    for j, _ in pupil_phase.terms:
        n, m = noll_to_nm(j)
        if m != 0:
            raise DesignError(
                f"pupil_phase.zernike_waves: Noll {j} (radial order n = {n}, azimuthal frequency m = {m}) is not "
                "rotationally symmetric, and a kind 'conventional' design takes only m = 0 terms: its "
                "native-image-plane field is the radial Debye integral, which assumes a rotationally symmetric "
                "pupil, so only a phase of the pupil radius can enter it. Fix: keep only Noll 1 (piston), 4 "
                "(defocus), 11 (primary spherical), 22 (secondary spherical), 37, ...; or use kind 'fourier'."
            )


def _check_pupil(design: Design) -> None:
    relay, diameter = design.relay, design.pupil_diameter_at_mla
    if (
        relay is None or diameter is None
    ):  # no relay, no pupil image (the caller checks kind 'fourier' has one)
        return
    radius = diameter / 2.0 / 1e-6  # um
    mla = design.mla
    outside, clipped = [], []
    for i, lens in enumerate(mla.lenslets):
        if math.hypot(*lens.center_um) > radius:
            outside.append(lens.describe(i))
        elif lens.reach_um > radius + 1e-5:
            clipped.append(f"{lens.describe(i)} reaches {fmt(lens.reach_um)} um")
    where = (
        f"the pupil image at the MLA has radius {fmt(radius)} um (NA f_relay / M = "
        f"{fmt(design.objective.numerical_aperture)} x {fmt(relay.focal_length_mm)} mm / "
        f"{fmt(design.objective.magnification)})"
    )
    if outside:
        raise DesignError(
            f"lenslet centres must lie inside the pupil image: {where}, but {list_pairs(outside)} lie outside. "
            "Fix: move those lenslets inward or remove them, or use a longer relay focal_length_mm."
        )
    if clipped:
        warn_design(
            f"lenslets partly outside the pupil image are vignetted ({where}): {list_pairs(clipped)}. "
            "Fix: move them inward or shrink their apertures, if the clipping is not intended."
        )


def _check_fourier_sub_images(design: Design) -> None:
    radius = design.sub_image_radius
    if radius is None:
        warn_design(
            "cannot check whether sub-images overlap: the field of view is unlimited (no objective "
            "field_number_mm and no relay field_stop_diameter_mm). Fix: give the objective's field number "
            "or the field-stop diameter at the native image plane."
        )
        return
    r_um, pixel_um = radius / 1e-6, design.camera.pixel_pitch_um
    lenslets = design.mla.lenslets
    centers = [lens.center_um for lens in lenslets]
    overlaps = disc_overlaps(centers, r_um, 0.5 * pixel_um)
    if overlaps:
        closest = min(math.dist(centers[i], centers[j]) for i, j, _ in overlaps)
        stop_mm = closest * 1e-3 * design.relay.focal_length_mm / design.mla_to_camera_distance_mm  # type: ignore[union-attr]
        pairs = [
            f"{lenslets[i].describe(i)} and {lenslets[j].describe(j)} by {fmt(depth)} um"
            for i, j, depth in overlaps
        ]
        warn_design(
            f"sub-images overlap on the sensor (each {fmt(2 * r_um)} um across): {list_pairs(pairs)}. "
            f"Fix: a field stop (relay field_stop_diameter_mm) of at most {fmt(stop_mm)} mm, lenslets further apart, "
            "or a shorter mla_to_camera_distance_mm."
        )
    half_w, half_h = (s / 2.0 / 1e-6 for s in design.camera.sensor_size)
    off, clipped = [], []
    for i, (x, y) in enumerate(centers):
        if abs(x) > half_w or abs(y) > half_h:
            off.append(lenslets[i].describe(i))
        elif abs(x) + r_um > half_w + 0.5 * pixel_um or abs(y) + r_um > half_h + 0.5 * pixel_um:
            clipped.append(lenslets[i].describe(i))
    sensor = f"the {fmt(2 * half_w)} x {fmt(2 * half_h)} um sensor"
    if off:
        raise DesignError(
            f"sub-images must be centred on {sensor}; those of {list_pairs(off)} are not. "
            "Fix: move those lenslets inward, or use a larger camera pixel_count."
        )
    if clipped:
        warn_design(
            f"sub-images ({fmt(2 * r_um)} um across) of {list_pairs(clipped)} are cut by the edge of {sensor}. "
            "Fix: move those lenslets inward, reduce the field stop, or use a larger camera pixel_count."
        )


def _check_lenslet_nyquist(design: Design) -> None:
    """Pixel pitch <= lambda f / (2 D): Nyquist for the lenslet's incoherent cutoff D / (lambda f)."""
    pixel_um, wavelength_um = design.camera.pixel_pitch_um, design.wavelength_nm * 1e-3
    worst = None
    for i, lens in enumerate(design.mla.lenslets):
        limit = wavelength_um * lens.focal_length_mm * 1e3 / (2.0 * lens.aperture_diameter_um)
        if pixel_um > limit and (worst is None or limit < worst[1]):
            worst = (i, limit)
    if worst is not None:
        i, limit = worst
        lens = design.mla.lenslets[i]
        warn_design(
            f"camera pixel_pitch_um {fmt(pixel_um)} um undersamples the sub-images: Nyquist for {lens.describe(i)} "
            f"(aperture_diameter_um {fmt(lens.aperture_diameter_um)}, focal_length_mm {fmt(lens.focal_length_mm)}) "
            f"needs at most lambda f / (2 D) = {fmt(limit)} um. Fix: smaller pixels, a longer lenslet focal length "
            f"(>= {fmt(lens.focal_length_mm * pixel_um / limit)} mm) or a smaller aperture "
            f"(<= {fmt(lens.aperture_diameter_um * limit / pixel_um)} um)."
        )


def _check_conventional_sub_images(design: Design) -> None:
    r_um = design.sub_image_radius / 1e-6  # type: ignore[operator]
    pixel_um = design.camera.pixel_pitch_um
    if 2.0 * r_um < MIN_PIXELS_PER_SUB_IMAGE * pixel_um:
        warn_design(
            f"each sub-image is {fmt(2 * r_um)} um across, only {fmt(2 * r_um / pixel_um)} camera pixels "
            f"(pixel_pitch_um {fmt(pixel_um)}); at least {MIN_PIXELS_PER_SUB_IMAGE} are needed to record "
            "directions. Fix: smaller pixels, a longer mla_to_camera_distance_mm with matching lenslet focal "
            "length, or a larger pitch."
        )
    mla = design.mla
    if isinstance(mla, RegularMLASpec):  # every lenslet has the same neighbours: check a 3 x 3 patch
        nx = min(mla.shape[1], 3)
        centers = mla.centers_um(limit=(3, 3))
        index = [(k // nx) * mla.shape[1] + k % nx for k in range(len(centers))]
    else:
        centers = [lens.center_um for lens in mla.lenslets]
        index = list(range(len(centers)))
    overlaps = disc_overlaps(centers, r_um, 0.5 * pixel_um)
    if overlaps:
        na, m = design.objective.numerical_aperture, design.objective.magnification
        pairs = [
            f"lenslets {index[i]} at {_xy(centers[i])} and {index[j]} at {_xy(centers[j])} by {fmt(depth)} um"
            for i, j, depth in overlaps
        ]
        warn_design(
            f"sub-images (pupil images, {fmt(2 * r_um)} um across) overlap: {list_pairs(pairs)}. The lenslet "
            f"f-number must be at least the image-side f-number M / (2 NA) = {fmt(m / (2 * na))}. Fix: shorten "
            f"mla_to_camera_distance_mm (and the lenslet focal length) or increase the pitch."
        )


def _xy(point: tuple[float, float]) -> str:
    return f"({fmt(point[0])}, {fmt(point[1])}) um"
