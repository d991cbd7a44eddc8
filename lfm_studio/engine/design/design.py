"""The Design: one light-field microscope, composed of validated part specs.

Two kinds (see :mod:`lfm_studio.engine.design.checks` for the geometry):

- ``"fourier"`` (XLFM, FLFM): objective + tube lens form the native image plane (NIP);
  a relay (Fourier) lens one focal length behind the NIP images the objective's
  back pupil onto the MLA; the camera sits ``mla_to_camera_distance_mm`` behind the
  MLA, at the lenslets' focal plane (between the focal planes of a multifocal array).
- ``"conventional"`` (Levoy 2006, Prevedel 2014): the MLA sits ON the native image
  plane (no relay), the camera at the lenslets' focal plane, so
  ``mla_to_camera_distance_mm`` is usually the lenslet focal length. A relay that
  re-images the lenslets' focal plane onto the sensor 1:1 is not modelled: give the
  camera the pixel pitch it has at that plane.
"""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import SerializationInfo, SerializerFunctionWrapHandler, model_serializer, model_validator

from lfm_studio.engine.design.accuracy import AccuracySpec
from lfm_studio.engine.design.base import SpecModel, si
from lfm_studio.engine.design.camera import CameraSpec
from lfm_studio.engine.design.checks import check_design
from lfm_studio.engine.design.depths import DepthSpec
from lfm_studio.engine.design.errors import DesignError, fmt, require_positive
from lfm_studio.engine.design.evolve import rebuild
from lfm_studio.engine.design.mla import AnyMLASpec
from lfm_studio.engine.design.objective import ObjectiveSpec, RelayLensSpec
from lfm_studio.engine.design.pupil_phase import PupilPhaseSpec

SCHEMA_VERSION = 1
"""Version of the design-file schema this lfm_studio writes (older ones are migrated on load)."""

METADATA_FIELDS = ("name", "description", "source", "assumed")
"""Fields that describe a design without changing its optics (left out of optics hashes)."""

Kind = Literal["fourier", "conventional"]


class Design(SpecModel):
    """A complete light-field microscope design.

    Attributes
    ----------
    schema_version : int
        Design-file schema version (:data:`SCHEMA_VERSION`).
    name, description : str
        Short name and free text.
    source : str
        Citation of the publication or instrument the design follows ("" if none).
    assumed : tuple of str
        Values that had to be assumed (not given by ``source``), one note each.
    kind : "fourier" or "conventional"
        Where the MLA sits (Fourier plane or native image plane).
    wavelength_nm : float
        Emission wavelength in vacuum, nanometres.
    objective : ObjectiveSpec
    relay : RelayLensSpec or None
        The Fourier lens; required for ``"fourier"``, must be None for ``"conventional"``.
    pupil_phase : PupilPhaseSpec or None
        A Zernike phase mask on the pupil, ``{"zernike_waves": {"4": 0.1}}``
        (:mod:`~lfm_studio.engine.design.pupil_phase`): any term on the relayed pupil (at the MLA
        plane) for ``"fourier"``; rotationally symmetric (m = 0) terms on the objective's back focal
        plane for ``"conventional"``.
        Left out of files and hashes when None, so designs without one keep theirs.
    mla : MLASpec or RegularMLASpec
    mla_to_camera_distance_mm : float
        Distance from the MLA to the sensor, millimetres.
    camera : CameraSpec
    depths : DepthSpec
    accuracy : AccuracySpec
    """

    schema_version: int = SCHEMA_VERSION
    name: str
    description: str = ""
    source: str = ""
    assumed: tuple[str, ...] = ()
    kind: Kind
    wavelength_nm: float
    objective: ObjectiveSpec
    relay: RelayLensSpec | None = None
    pupil_phase: PupilPhaseSpec | None = None
    mla: AnyMLASpec
    mla_to_camera_distance_mm: float
    camera: CameraSpec
    depths: DepthSpec
    accuracy: AccuracySpec = AccuracySpec.from_preset("standard")

    @model_validator(mode="after")
    def _check(self) -> Design:
        if self.schema_version != SCHEMA_VERSION:
            raise DesignError(
                f"schema_version must be {SCHEMA_VERSION} for a Design object; got {self.schema_version}. "
                "Fix: read older files with load_design / design_from_json, which migrate them."
            )
        require_positive(
            "wavelength_nm", self.wavelength_nm, "nm", "e.g. 525 (emission wavelength in nanometres)."
        )
        if not 100.0 <= self.wavelength_nm <= 20000.0:
            raise DesignError(
                f"wavelength_nm must be between 100 and 20000 nm; got {fmt(self.wavelength_nm)} nm. "
                "Fix: give the emission wavelength in nanometres, e.g. 525 (not 0.525 um or 5.25e-7 m)."
            )
        require_positive(
            "mla_to_camera_distance_mm",
            self.mla_to_camera_distance_mm,
            "mm",
            "e.g. the lenslet focal length.",
        )
        check_design(self)
        return self

    @model_serializer(mode="wrap")
    def _drop_absent_pupil_phase(
        self, handler: SerializerFunctionWrapHandler, info: SerializationInfo
    ) -> dict[str, Any]:
        # A design without a phase mask dumps (and so writes and hashes) as before the field existed.
        data: dict[str, Any] = handler(self)
        if data.get("pupil_phase", 0) is None:
            del data["pupil_phase"]
        return data

    # ----- SI accessors and derived geometry (metres) -----

    @property
    def wavelength(self) -> float:
        """Emission wavelength in vacuum, metres."""
        return si(self.wavelength_nm, "nm")

    @property
    def mla_to_camera_distance(self) -> float:
        """MLA-to-sensor distance, metres."""
        return si(self.mla_to_camera_distance_mm, "mm")

    @property
    def pupil_diameter_at_mla(self) -> float | None:
        """Fourier LFM: diameter of the pupil image on the MLA, ``2 NA f_relay / M``, metres (else None)."""
        if self.relay is None:
            return None
        return (
            2.0 * self.objective.numerical_aperture * self.relay.focal_length / self.objective.magnification
        )

    @property
    def magnification(self) -> float:
        """Lateral magnification sample -> sensor: ``M`` (conventional, at the NIP) or ``M d / f_relay`` (Fourier)."""
        if self.relay is None:
            return self.objective.magnification
        return self.objective.magnification * self.mla_to_camera_distance / self.relay.focal_length

    @property
    def field_of_view_diameter(self) -> float | None:
        """Field of view at the sample allowed by the field number and the field stop, metres (None: unlimited)."""
        limits = [self.objective.field_of_view_diameter]
        if self.relay is not None and self.relay.field_stop_diameter is not None:
            limits.append(self.relay.field_stop_diameter / self.objective.magnification)
        known = [x for x in limits if x is not None]
        return min(known) if known else None

    @property
    def sub_image_radius(self) -> float | None:
        """Radius of each lenslet's sub-image on the sensor, metres (None: field unlimited, Fourier kind)."""
        d = self.mla_to_camera_distance
        if self.relay is None:
            sin_image = self.objective.numerical_aperture / self.objective.magnification
            return d * math.tan(math.asin(sin_image))
        fov = self.field_of_view_diameter
        if fov is None:
            return None
        return d * fov * self.objective.magnification / (2.0 * self.relay.focal_length)

    # ----- changing a design -----

    def updated(self, **changes: Any) -> Design:
        """A new, fully validated design with top-level fields replaced (``design.updated(wavelength_nm=600)``).

        Values may be specs or plain dicts (validated like a file). For a nested value use
        :func:`~lfm_studio.engine.design.evolve`, e.g. ``evolve(design, "objective.numerical_aperture", 0.8)``.
        """
        return rebuild(self, changes)
