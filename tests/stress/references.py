"""Independent numpy references for the stress tests (no engine code)."""

from __future__ import annotations

import math

import numpy as np

from lfm_studio.engine.design import Design

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(48)


def pupil_intensity(design: Design, r: np.ndarray) -> np.ndarray:
    """Irradiance (W/m^2) on the MLA of a unit-power isotropic emitter on axis, at radius ``r`` (m).

    The aplanatic objective sends equal power into equal solid angles: the back-pupil
    irradiance at ``rho = n f sin(theta)`` is ``1 / (4 pi n^2 f^2 cos(theta))`` (the Jacobian of
    the sine condition); the paraxial model drops ``1/cos``. The relay scales lengths by
    ``m_r = f_relay / f_tube`` and the irradiance by ``1 / m_r^2``. Zero outside the pupil.
    """
    obj = design.objective
    n, f = obj.immersion_index, obj.focal_length
    m_r = design.relay.focal_length / obj.tube_lens_focal_length
    sin_t = r / (m_r * n * f)
    inside = sin_t <= obj.numerical_aperture / n * (1 + 1e-12)
    cos_t = np.sqrt(np.clip(1.0 - sin_t**2, 1e-300, None))
    amplitude = 1.0 / cos_t if design.accuracy.objective_model == "debye" else np.ones_like(r)
    return np.where(inside, amplitude / (4.0 * math.pi * n**2 * f**2 * m_r**2), 0.0)


def lenslet_power(design: Design) -> float:
    """Power (W) of a unit emitter that passes the lenslet apertures, by Gauss-Legendre quadrature.

    Squares: a 48 x 48 tensor rule over the square; circles: 48 x 48 in polar coordinates
    around the lenslet centre. The integrand is smooth (``1 / cos(theta)``) where the aperture
    lies inside the pupil, so the rule is exact to ~1e-12 there.
    """
    total = 0.0
    for lens in design.mla.lenslets:
        cx, cy = lens.center
        half = lens.aperture_diameter / 2.0
        if lens.shape == "square":
            u = half * _NODES
            x, y = np.meshgrid(cx + u, cy + u, indexing="xy")
            w = np.outer(_WEIGHTS, _WEIGHTS) * half * half
        else:
            rho = half * (_NODES + 1.0) / 2.0
            phi = math.pi * (_NODES + 1.0)
            rr, pp = np.meshgrid(rho, phi, indexing="ij")
            x, y = cx + rr * np.cos(pp), cy + rr * np.sin(pp)
            w = np.outer(_WEIGHTS * half / 2.0 * rho, _WEIGHTS * math.pi)
        total += float((w * pupil_intensity(design, np.hypot(x, y))).sum())
    return total


def collected_fraction(design: Design) -> float:
    """``(1 - cos(alpha)) / 2``: the fraction of a unit isotropic emitter's power the objective collects."""
    obj = design.objective
    return (1.0 - math.cos(math.asin(obj.numerical_aperture / obj.immersion_index))) / 2.0
