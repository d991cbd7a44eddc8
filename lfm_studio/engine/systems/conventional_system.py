"""Engine-side description of a conventional light-field microscope (SI units).

Light path (Levoy 2006, Broxton 2013; thesis eqs. 3.21-3.22): objective and tube lens
image the sample onto the native image plane (NIP), inverted and magnified ``M``; a
square microlens array of pitch ``P`` sits on the NIP; the camera is
``mla_to_camera`` behind it (usually the lenslet focal length).

The raw camera image is rectified (resampled) so that each lenslet covers exactly
``pixels_per_lenslet`` (odd) pixels per axis, the usual first step of LFM processing;
the volume has ``voxels_per_lenslet`` (odd) voxels per lenslet pitch laterally, i.e.
a lateral voxel of ``P / (M * voxels_per_lenslet)`` in the sample. Both odd counts
put a pixel and a voxel on each lenslet axis, which keeps the array's symmetries.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

from lfm_studio.engine.errors import require_positive
from lfm_studio.engine.optics.objective import ObjectiveLens, _value
from lfm_studio.engine.optics.zernike import check_rotationally_symmetric, radial_slope_bound


@dataclass(frozen=True)
class ConventionalLFMSystem:
    """A conventional LFM on a square lenslet lattice, lengths in metres.

    Attributes
    ----------
    objective : ObjectiveLens.
    pitch : lenslet pitch on the NIP, m.
    lenslet_focal_length : m.
    lenslet_shape : ``"square"`` or ``"circle"``: the clear aperture of each lenslet.
    mla_to_camera : MLA-to-sensor distance, m.
    lenslets : (ny, nx) lenslets imaged (the sensor region used).
    pixels_per_lenslet : rectified sensor pixels per lenslet per axis (odd).
    voxels_per_lenslet : volume voxels per lenslet pitch per axis (odd; lateral super-sampling).
    wavelength : emission wavelength, m.
    lenslet_aperture : clear aperture of a lenslet, m: the side (square) or diameter (circle),
        ``0 < lenslet_aperture <= pitch``, centred on the lenslet; ``None`` (default) means the
        pitch (a square array then has fill factor 1). The sampling grid is planned from the
        pitch either way; light outside the aperture is blocked.
    pupil_zernike_waves : phase mask on the objective's back focal plane, ``((noll index, waves), ...)``,
        rotationally symmetric (``m = 0``) terms only (Noll 1, 4, 11, 22, 37, ...; others raise
        ``ValueError``): the phase ``2 pi sum_j c_j Z_j(rho)`` enters the Debye integrand of the
        native-image-plane field at ``rho = sin(theta) / sin(alpha)`` (:func:`debye_integral`).
        Sorted by index; ``()`` (default) is no mask. Part of the system's identity (hash, equality).
    """

    objective: ObjectiveLens
    pitch: float
    lenslet_focal_length: float
    lenslet_shape: str
    mla_to_camera: float
    lenslets: tuple[int, int]
    pixels_per_lenslet: int
    voxels_per_lenslet: int
    wavelength: float
    lenslet_aperture: float | None = None
    pupil_zernike_waves: tuple[tuple[int, float], ...] = ()

    def __post_init__(self) -> None:
        require_positive("pitch", self.pitch, "m", "e.g. 125 * um.")
        require_positive("lenslet_focal_length", self.lenslet_focal_length, "m", "e.g. 1.875 * mm.")
        require_positive("mla_to_camera", self.mla_to_camera, "m", "usually the lenslet focal length.")
        require_positive("wavelength", self.wavelength, "m", "e.g. 525 * nm.")
        if self.lenslet_aperture is not None:
            require_positive("lenslet_aperture", self.lenslet_aperture, "m", "or None for the pitch.")
            if self.lenslet_aperture > self.pitch:
                raise ValueError(
                    f"lenslet_aperture must be at most the pitch ({self.pitch:.6g} m); got "
                    f"{self.lenslet_aperture:.6g} m. Fix: use an aperture <= pitch, or None for the pitch."
                )
        if self.lenslet_shape not in ("square", "circle"):
            raise ValueError(f"lenslet_shape must be 'square' or 'circle'; got {self.lenslet_shape!r}.")
        for name in ("pixels_per_lenslet", "voxels_per_lenslet"):
            value = getattr(self, name)
            if int(value) != value or value < 1 or value % 2 == 0:
                raise ValueError(f"{name} must be an odd integer >= 1; got {value!r}. Fix: use e.g. 15 or 5.")
        ny, nx = self.lenslets
        if int(ny) != ny or int(nx) != nx or ny < 1 or nx < 1:
            raise ValueError(f"lenslets must be two positive integers (ny, nx); got {self.lenslets!r}.")
        object.__setattr__(self, "lenslets", (int(ny), int(nx)))
        terms = tuple((j, float(c)) for j, c in self.pupil_zernike_waves)
        check_rotationally_symmetric([j for j, _ in terms], "pupil_zernike_waves")
        if len({j for j, _ in terms}) != len(terms):
            raise ValueError(f"pupil_zernike_waves lists a Noll index twice: {terms}.")
        object.__setattr__(self, "pupil_zernike_waves", tuple(sorted(terms)))

    @property
    def magnification(self) -> float:
        """Lateral magnification sample -> NIP (the image is inverted)."""
        return float(_value(self.objective.magnification))

    @property
    def aperture(self) -> float:
        """Clear aperture of a lenslet (side or diameter), m: ``lenslet_aperture``, else the pitch."""
        return self.pitch if self.lenslet_aperture is None else self.lenslet_aperture

    @property
    def pixel_size(self) -> float:
        """Rectified sensor pixel pitch, ``P / pixels_per_lenslet``, m."""
        return self.pitch / self.pixels_per_lenslet

    @property
    def voxel_size(self) -> float:
        """Lateral voxel size in the sample, ``P / (M voxels_per_lenslet)``, m."""
        return self.pitch / (self.magnification * self.voxels_per_lenslet)

    def blur_radius(self, depth: float) -> float:
        """Geometric radius on the NIP of the defocused image of a point at ``depth``, m.

        Image-side defocus ``M^2 z / n`` times the image-side aperture slope
        ``tan(asin(NA / M))``, plus (with a pupil phase) the mask's largest transverse ray
        aberration ``lambda M / NA max |dW/drho|`` (``W`` in waves, :func:`radial_slope_bound`):
        an upper bound of the two together. Without a mask, exactly the defocus blur.
        """
        m = self.magnification
        n = float(_value(self.objective.immersion_index))
        na = float(_value(self.objective.numerical_aperture))
        blur = abs(depth) * m * m / n * math.tan(math.asin(min(na / m, 0.999)))
        if self.pupil_zernike_waves:
            blur += self.wavelength * m / na * _mask_slope(self.pupil_zernike_waves)
        return blur

    def support(self, depth: float) -> int:
        """Lenslets on each side of the source's lenslet that receive its light at ``depth``."""
        return math.ceil(self.blur_radius(depth) / self.pitch + 0.5) + 1


@lru_cache(maxsize=256)
def _mask_slope(terms: tuple[tuple[int, float], ...]) -> float:
    """:func:`radial_slope_bound` of a system's (hashable) pupil terms, computed once per mask."""
    return radial_slope_bound(dict(terms))
