"""The camera conversion of frames a calibration has already dark-subtracted.

A calibration subtracts its dark frame (or dark level) from every raw frame
(:func:`~lfm_studio.engine.calibration.correct_frame`), so the ADU -> photon conversion that
follows (:func:`lfm_studio.engine.io.counts_to_photons`) must use a baseline of 0, or the
dark level would be subtracted twice. Gain, quantum efficiency and read noise come from the
caller (``--gain/--read-noise``), else the frame's camera metadata, else the calibration's
nominal design camera.
"""

from __future__ import annotations

from typing import Any

from lfm_studio.engine.calibration.fitted_design import nominal_design
from lfm_studio.engine.calibration.record import Calibration
from lfm_studio.engine.io.camera_counts import CameraCalibration, calibration_from_metadata


def dark_subtracted_camera(
    calibration: Calibration,
    metadata: dict[str, Any] | None = None,
    *,
    gain: float | None = None,
    read_noise: float | None = None,
    quantum_efficiency: float | None = None,
    source: str = "calibration (dark subtracted)",
) -> CameraCalibration:
    """Baseline 0; ``gain`` (ADU per electron), ``read_noise`` (electrons rms) and
    ``quantum_efficiency`` (photo-electrons per photon) if given, else the frame's ``metadata``
    camera, else the calibration's design camera."""
    recorded = calibration_from_metadata(metadata)
    camera = recorded if recorded is not None else nominal_design(calibration).camera
    return CameraCalibration(
        baseline_adu=0.0,
        gain_adu_per_e=float(camera.gain_adu_per_e if gain is None else gain),
        quantum_efficiency=float(
            camera.quantum_efficiency if quantum_efficiency is None else quantum_efficiency
        ),
        source=source,
        read_noise_e=float(camera.read_noise_e if read_noise is None else read_noise),
    )
