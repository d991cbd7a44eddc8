"""A phase mask on the pupil, as Zernike coefficients (the design's ``pupil_phase``).

Fourier LFM: the mask sits on the MLA plane, where the relay images the objective's back
pupil (the plane a phase plate or an SLM in the relay would occupy), and is written as Noll
Zernike polynomials with unit RMS over the relayed pupil, radius ``NA f_relay / M``
(:mod:`lfm_studio.engine.optics.zernike`), in MLA-plane coordinates (``x``, ``y`` as the
lenslet centres and the sensor). The relay inverts the image, so in the objective's own
back focal plane the odd-``m`` terms (tilt, coma, ...) change sign.

In a design file::

    "pupil_phase": {"zernike_waves": {"4": 0.1, "11": -0.05}}

maps Noll index to coefficient in waves (phase ``2 pi c Z_j``). Conventional designs take
rotationally symmetric terms only (``m = 0``: Noll 1, 4, 11, 22, 37, ...; :func:`~lfm_studio.engine.optics.zernike.noll_to_nm`),
on the objective's back focal plane, normalised to its radius ``NA f_obj`` (the Debye
integrand's ``rho = sin(theta) / sin(alpha)``); other terms are refused by name
(:func:`~lfm_studio.engine.design.checks.check_design`).
"""

from __future__ import annotations

import math

from pydantic import field_validator

from lfm_studio.engine.design.base import SpecModel
from lfm_studio.engine.design.errors import DesignError, fmt


class PupilPhaseSpec(SpecModel):
    """Zernike phase on the pupil: the relayed pupil of a Fourier LFM, the objective's back focal
    plane of a conventional one (m = 0 terms only there).

    Attributes
    ----------
    zernike_waves : dict of Noll index (>= 1) to coefficient in waves
        Phase ``2 pi sum_j c_j Z_j(x / R, y / R)`` on the MLA plane, ``R = NA f_relay / M``,
        ``Z_j`` of unit RMS over the pupil. Stored in ascending index order; a listed 0.0
        is kept (a term a design space can free).
    """

    zernike_waves: dict[int, float]

    @field_validator("zernike_waves", mode="after")
    @classmethod
    def _check_terms(cls, value: dict[int, float]) -> dict[int, float]:
        for j, c in value.items():
            if j < 1:
                raise DesignError(
                    f"pupil_phase.zernike_waves: Noll indices must be integers >= 1; got {j}. "
                    "Fix: e.g. 4 (defocus), 11 (primary spherical)."
                )
            if not math.isfinite(c):
                raise DesignError(
                    f"pupil_phase.zernike_waves[{j}] must be a finite number of waves; got {fmt(c)}. Fix: e.g. 0.1."
                )
        return dict(sorted(value.items()))

    @property
    def terms(self) -> tuple[tuple[int, float], ...]:
        """``((noll index, waves), ...)`` in ascending index order (hashable, for the engine)."""
        return tuple(self.zernike_waves.items())
