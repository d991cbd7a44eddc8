"""The objective lens: an infinity-corrected, aplanatic lens and its paraxial imaging map.

Geometry (all SI). An objective of magnification ``M`` used with a tube lens of focal
length ``f_tube`` has the focal length ``f_obj = f_tube / M``. A ray leaving the focal
point at angle ``theta`` in the immersion medium (index ``n``) crosses the back focal
plane (the pupil) at height ``rho = n f_obj sin(theta)`` (Abbe sine condition), so the
pupil radius is ``NA f_obj`` and the half-angle is ``alpha = asin(NA / n)``.

Axial convention used by this module, :mod:`debye` and :mod:`pupil_field`: the
source depth ``z`` is measured from the focal plane AWAY from the objective (deeper
into the sample, against the light's direction of travel towards the camera). A
source at ``z`` puts the phase ``exp(+j n k z cos(theta))`` on the plane wave it sends
at angle ``theta`` (``k = 2 pi / lambda``, time dependence ``exp(-j w t)``).

Apodization ``P(theta)`` is the amplitude weight of the angular spectrum in the
Debye integral (thesis eq. 3.14): ``"aplanatic"`` ``sqrt(cos theta)`` (an aplanatic
objective imaging an isotropic emitter, Richards-Wolf / Gu), ``"flat"`` 1, ``"cos"``
``cos theta`` (Gu's Herschel-condition pupil, which focuses to the exact Airy
pattern), or any callable ``theta -> P`` on a float64 tensor of angles in radians.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from lfm_studio.engine.errors import require_positive

Scalar = float | torch.Tensor
Apodization = str | Callable[[torch.Tensor], torch.Tensor]

APODIZATIONS: dict[str, Callable[[torch.Tensor], torch.Tensor]] = {
    "aplanatic": lambda theta: torch.sqrt(torch.cos(theta)),
    "flat": lambda theta: torch.ones_like(theta),
    "cos": lambda theta: torch.cos(theta),
}


def resolve_apodization(apodization: Apodization) -> Callable[[torch.Tensor], torch.Tensor]:
    """The function ``P(theta)`` named by ``apodization`` (a key of ``APODIZATIONS`` or a callable)."""
    if callable(apodization):
        return apodization
    if apodization not in APODIZATIONS:
        raise ValueError(
            f"apodization must be one of {sorted(APODIZATIONS)} or a callable theta -> P(theta); "
            f"got {apodization!r}. Fix: use 'aplanatic' for a real objective."
        )
    return APODIZATIONS[apodization]


def _value(x: Scalar) -> float:
    return float(x.detach()) if isinstance(x, torch.Tensor) else float(x)


def _check_scalar(name: str, value: Scalar, unit: str, fix: str) -> None:
    if isinstance(value, torch.Tensor) and value.ndim != 0:
        raise ValueError(
            f"{name} must be a number or a 0-d tensor; got a tensor of shape {tuple(value.shape)}."
        )
    require_positive(name, value, unit, fix)


@dataclass(frozen=True)
class ObjectiveLens:
    """An infinity-corrected objective (engine-side, SI units).

    Attributes
    ----------
    magnification : float or 0-d tensor
        Lateral magnification ``M`` with the tube lens below (dimensionless, > 0).
    numerical_aperture : float or 0-d tensor
        ``NA = n sin(alpha)``, dimensionless, ``0 < NA < immersion_index``. A tensor
        with ``requires_grad`` makes the Debye PSF differentiable with respect to it.
    immersion_index : float or 0-d tensor
        Refractive index ``n`` of the immersion medium / sample (1.0 air, 1.33 water,
        1.518 oil).
    tube_lens_focal_length : float or 0-d tensor
        Focal length of the tube lens in metres (e.g. ``200 * mm`` for Nikon/Zeiss-style
        systems, ``180 * mm`` for Olympus).
    """

    magnification: Scalar
    numerical_aperture: Scalar
    immersion_index: Scalar
    tube_lens_focal_length: Scalar

    def __post_init__(self) -> None:
        _check_scalar("magnification", self.magnification, "", "pass the objective's magnification, e.g. 20.")
        _check_scalar("numerical_aperture", self.numerical_aperture, "", "pass e.g. 0.5.")
        _check_scalar(
            "immersion_index", self.immersion_index, "", "use 1.0 (air), 1.33 (water), 1.518 (oil)."
        )
        _check_scalar(
            "tube_lens_focal_length", self.tube_lens_focal_length, "m", "give it in metres, e.g. 200 * mm."
        )
        na, n = _value(self.numerical_aperture), _value(self.immersion_index)
        if na >= n:
            verb = "exceeds" if na > n else "equals"
            raise ValueError(
                f"numerical_aperture {na:g} {verb} immersion_index {n:g}; NA = n sin(alpha) must be "
                f"below n. Fix: lower the NA below {n:g} or use a denser immersion medium "
                "(water 1.33, glycerol 1.47, oil 1.518)."
            )

    # -- derived quantities (tensors when the inputs are tensors) ------------------
    @property
    def focal_length(self) -> Scalar:
        """Objective focal length ``f_obj = f_tube / M`` in metres."""
        return self.tube_lens_focal_length / self.magnification

    @property
    def pupil_radius(self) -> Scalar:
        """Back-aperture radius ``NA f_obj`` in metres (Abbe sine condition)."""
        return self.numerical_aperture * self.focal_length

    @property
    def half_angle(self) -> Scalar:
        """Aperture half-angle ``alpha = asin(NA / n)`` in radians (in the immersion medium)."""
        ratio = self.numerical_aperture / self.immersion_index
        return torch.asin(ratio) if isinstance(ratio, torch.Tensor) else math.asin(ratio)

    @property
    def axial_magnification(self) -> Scalar:
        """Paraxial axial magnification ``M^2 / n`` into an image space of index 1 (air)."""
        return self.magnification**2 / self.immersion_index


def image_point(
    objective: ObjectiveLens,
    position: Sequence[float] | torch.Tensor,
    *,
    image_index: float = 1.0,
) -> tuple[float, float, float] | torch.Tensor:
    """Paraxial image of a point source through objective + tube lens.

    ``(x, y, z) -> (-M x, -M y, (image_index / n) M^2 z)``: the lateral image is
    inverted and magnified by ``M``; the axial magnification is ``M^2 n'/n``
    (Herschel/Lagrange, paraxial), where ``n`` is the immersion index and
    ``n' = image_index`` that of the image space. ``z`` is the source depth
    (positive away from the objective, see the module docstring); the image depth is
    measured from the nominal image plane with the same orientation, so a positive
    ``z'`` lies before the image plane, towards the tube lens.

    Parameters
    ----------
    objective : ObjectiveLens
    position : (x, y, z) in metres, or a tensor of shape ``(..., 3)``.
    image_index : refractive index of the image space (1.0 for air).

    Returns
    -------
    A tuple of floats for a sequence input, else a tensor of shape ``(..., 3)`` in metres.
    """
    require_positive("image_index", image_index, "", "use 1.0 for air.")
    m = objective.magnification
    axial = m**2 * image_index / objective.immersion_index
    if isinstance(position, torch.Tensor):
        if position.shape[-1:] != (3,):
            raise ValueError(
                f"position must have a last dimension of 3 (x, y, z); got {tuple(position.shape)}."
            )
        parts = [torch.as_tensor(v, dtype=position.dtype).to(position.device) for v in (-m, -m, axial)]
        return position * torch.stack(parts)
    if len(position) != 3:
        raise ValueError(f"position must be (x, y, z) in metres; got {position!r}.")
    x, y, z = (float(v) for v in position)
    return (-_value(m) * x, -_value(m) * y, _value(axial) * z)
