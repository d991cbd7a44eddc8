"""The camera sensor: geometry and the noise parameters the sensor stage needs."""

from __future__ import annotations

import math

from pydantic import model_validator

from lfm_studio.engine.design.base import SpecModel, si
from lfm_studio.engine.design.errors import DesignError, fmt, require_positive


class CameraSpec(SpecModel):
    """A pixelated sensor centred on the optical axis.

    Attributes
    ----------
    pixel_pitch_um : float
        Pixel pitch in micrometres (square pixels).
    pixel_count : (ny, nx)
        Number of pixels along y (rows) and x (columns).
    quantum_efficiency : float
        Fraction of photons detected at the emission wavelength, in (0, 1].
    read_noise_e : float
        Gaussian read noise, electrons rms (>= 0).
    bit_depth : int
        ADC resolution in bits (1-32).
    gain_adu_per_e : float
        Conversion gain, ADU per electron (> 0).
    baseline_adu : float
        Offset added to every pixel, ADU, in ``[0, 2^bit_depth)``.
    full_well_e : float or None
        Full-well capacity in electrons (None: no saturation of the well).
    """

    pixel_pitch_um: float
    pixel_count: tuple[int, int]
    quantum_efficiency: float = 1.0
    read_noise_e: float = 0.0
    bit_depth: int = 16
    gain_adu_per_e: float = 1.0
    baseline_adu: float = 0.0
    full_well_e: float | None = None

    @model_validator(mode="after")
    def _check(self) -> CameraSpec:
        require_positive(
            "pixel_pitch_um", self.pixel_pitch_um, "um", "give the sensor pixel pitch, e.g. 6.5."
        )
        ny, nx = self.pixel_count
        if ny < 1 or nx < 1:
            raise DesignError(
                f"pixel_count must be (ny, nx) with both >= 1; got {self.pixel_count}. Fix: e.g. (2048, 2048)."
            )
        if not 0.0 < self.quantum_efficiency <= 1.0:
            raise DesignError(
                f"quantum_efficiency must be in (0, 1]; got {fmt(self.quantum_efficiency)}. "
                "Fix: give a fraction, e.g. 0.8 for 80 %."
            )
        if not (math.isfinite(self.read_noise_e) and self.read_noise_e >= 0.0):
            raise DesignError(
                f"read_noise_e must be >= 0 e- rms; got {fmt(self.read_noise_e)} e-. Fix: e.g. 1.5."
            )
        if not 1 <= self.bit_depth <= 32:
            raise DesignError(f"bit_depth must be 1-32 bits; got {self.bit_depth}. Fix: e.g. 16.")
        require_positive("gain_adu_per_e", self.gain_adu_per_e, "ADU/e-", "e.g. 0.5.")
        if not 0.0 <= self.baseline_adu < 2**self.bit_depth:
            raise DesignError(
                f"baseline_adu must be in [0, {2**self.bit_depth}) ADU for a {self.bit_depth}-bit camera; "
                f"got {fmt(self.baseline_adu)} ADU. Fix: e.g. 100."
            )
        if self.full_well_e is not None:
            require_positive("full_well_e", self.full_well_e, "e-", "e.g. 30000, or leave it out.")
        return self

    @property
    def pixel_pitch(self) -> float:
        """Pixel pitch in metres."""
        return si(self.pixel_pitch_um, "um")

    @property
    def sensor_size(self) -> tuple[float, float]:
        """Sensor width (x) and height (y) in metres."""
        ny, nx = self.pixel_count
        return (nx * self.pixel_pitch, ny * self.pixel_pitch)
