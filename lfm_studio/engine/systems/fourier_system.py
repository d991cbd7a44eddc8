"""Engine-side description of a Fourier light-field microscope (SI units).

Light path (thesis section 3.2.2, eq. 3.23): a point source in the sample; the
objective's back focal plane (BFP) holds the pupil field; the tube lens and the
Fourier lens relay the BFP onto the microlens array with magnification
``m_r = f_fourier / f_tube`` (a 4f relay, image inverted); each lenslet focuses its
part of the pupil onto the camera, ``mla_to_camera`` behind the array.

Sensor coordinates equal MLA-plane coordinates (both centred on the optical axis):
the chief ray through a lenslet centre runs parallel to the axis for an on-axis
source, so lenslet ``i``'s sub-image of the native focal plane is centred on the
sensor at the lenslet centre. A lateral source shift ``x0`` tilts the relayed pupil
field by ``x0 / (m_r f_obj)`` and moves every sub-image by
``M_total x0`` with ``M_total = M_obj * mla_to_camera / f_fourier``, the same for all
lenslets whatever their focal length, which is what makes the system laterally
shift-invariant (in the paraxial limit; tested).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lfm_studio.engine.errors import require_positive
from lfm_studio.engine.optics.mla_layout import MicrolensArray
from lfm_studio.engine.optics.objective import ObjectiveLens, _value
from lfm_studio.engine.optics.zernike import check_zernike_terms


@dataclass(frozen=True)
class FourierLFMSystem:
    """A Fourier LFM / XLFM, all lengths in metres.

    Attributes
    ----------
    objective : ObjectiveLens (magnification, NA, immersion index, tube lens).
    fourier_focal_length : focal length of the Fourier (relay) lens, m.
    mla : MicrolensArray on the BFP-conjugate plane (centres in MLA-plane metres).
    mla_to_camera : distance from the MLA to the sensor, m.
    pixel_pitch : sensor pixel pitch, m.
    sensor_shape : (ny, nx) sensor pixels; the optical axis is at pixel ``(ny//2, nx//2)``.
    wavelength : emission wavelength in vacuum, m.
    pupil_zernike_waves : phase mask on the relayed pupil, ``((noll index, waves), ...)``:
        unit-RMS Noll Zernikes over the pupil of radius :attr:`pupil_radius_at_mla`, in
        MLA-plane coordinates (:func:`~lfm_studio.engine.optics.pupil_field.pupil_terms_at`
        applies it for both PSF paths). Empty: no mask.
    """

    objective: ObjectiveLens
    fourier_focal_length: float
    mla: MicrolensArray
    mla_to_camera: float
    pixel_pitch: float
    sensor_shape: tuple[int, int]
    wavelength: float
    pupil_zernike_waves: tuple[tuple[int, float], ...] = ()

    def __post_init__(self) -> None:
        require_positive("fourier_focal_length", self.fourier_focal_length, "m", "e.g. 100 * mm.")
        require_positive("mla_to_camera", self.mla_to_camera, "m", "usually the lenslet focal length.")
        require_positive("pixel_pitch", self.pixel_pitch, "m", "e.g. 6.5 * um.")
        require_positive("wavelength", self.wavelength, "m", "e.g. 525 * nm.")
        ny, nx = self.sensor_shape
        if int(ny) != ny or int(nx) != nx or ny < 1 or nx < 1:
            raise ValueError(f"sensor_shape must be two positive integers; got {self.sensor_shape!r}.")
        object.__setattr__(self, "sensor_shape", (int(ny), int(nx)))
        terms = tuple((j, float(c)) for j, c in self.pupil_zernike_waves)
        check_zernike_terms([j for j, _ in terms], "pupil_zernike_waves")
        if len({j for j, _ in terms}) != len(terms):
            raise ValueError(f"pupil_zernike_waves lists a Noll index twice: {terms}.")
        object.__setattr__(self, "pupil_zernike_waves", tuple(sorted(terms)))

    @property
    def relay_magnification(self) -> float:
        """``m_r = f_fourier / f_tube``: BFP -> MLA-plane scale."""
        return float(self.fourier_focal_length / _value(self.objective.tube_lens_focal_length))

    @property
    def pupil_radius_at_mla(self) -> float:
        """Radius of the relayed pupil on the MLA, ``NA f_obj m_r``, in metres."""
        return _value(self.objective.pupil_radius) * self.relay_magnification

    @property
    def magnification(self) -> float:
        """Lateral magnification sample -> sensor, ``M_obj d / f_fourier``."""
        return _value(self.objective.magnification) * self.mla_to_camera / self.fourier_focal_length

    def max_slope(self, depth: float, radius_at_mla: float) -> float:
        """Largest ray slope (direction cosine, air) leaving the relayed pupil at ``radius_at_mla``.

        The defocus phase ``n k z (cos(theta) - 1)`` with ``sin(theta) = rho / (n f_obj)``,
        ``rho = r / m_r``, has the radial slope ``z rho / (n f_obj^2 cos(theta) m_r)`` (per
        unit ``k``); ``rho`` is capped at the pupil edge.
        """
        n = _value(self.objective.immersion_index)
        f_obj = _value(self.objective.focal_length)
        m_r = self.relay_magnification
        rho = min(radius_at_mla, self.pupil_radius_at_mla) / m_r
        sin_t = min(rho / (n * f_obj), 1.0 - 1e-12)
        return abs(depth) * rho / (n * f_obj**2 * math.sqrt(1.0 - sin_t**2) * m_r)
