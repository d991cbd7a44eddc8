"""Camera counts (ADU) <-> photons: the camera metadata an image carries, and the conversion back.

``lfm-studio image`` writes what a real camera writes, integer ADU (uint16 for a bit
depth <= 16), and records in the image metadata (key ``"camera"``) what is needed to
undo the camera::

    {"baseline_adu": 100.0, "gain_adu_per_e": 2.0, "quantum_efficiency": 0.8,
     "read_noise_e": 1.5, "bit_depth": 16, "full_well_e": 30000.0,
     "photons": 1e6, "seed": 1}

with ``"units": "ADU"``. Reconstruction turns counts back into photons at the camera,

    photons = max(ADU - baseline, 0) / gain / QE        (gain in ADU per electron)

clipped at 0 (negative values are read noise below the baseline), so a volume
reconstructed from them is in photons per voxel, the unit of the ground truth that
``image --truth`` writes: the volume that, projected through the PSF stack, gives the
expected photons at the camera (per bead, the photons it emits in the PSF's normalisation). A TIFF without this metadata (a measured camera frame) gets
the baseline and gain from the caller, or else a baseline estimated from the darkest
pixels (:func:`estimate_baseline`) with a warning that names the estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

#: Percentile of the frame taken as the baseline when nothing gives it (the darkest 1 %).
BASELINE_PERCENTILE = 1.0
#: The ``units`` of an image in camera counts; a noise-free image is already in photons.
ADU, PHOTONS = "ADU", "photons"


@dataclass(frozen=True)
class CameraCalibration:
    """How to undo a camera: ``photons = max(ADU - baseline_adu, 0) / gain_adu_per_e / quantum_efficiency``.

    ``source`` says where the values came from (shown to the user): ``"image metadata"``,
    ``"--baseline/--gain"``, ``"estimated"`` or ``"noise-free image"``; ``gain_known`` is
    False when the gain was assumed (the result is then in ADU above the baseline).
    """

    baseline_adu: float = 0.0
    gain_adu_per_e: float = 1.0
    quantum_efficiency: float = 1.0
    source: str = "image metadata"
    gain_known: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.baseline_adu) and self.baseline_adu >= 0):
            raise ValueError(
                f"baseline must be a finite number >= 0 ADU; got {self.baseline_adu!r}. "
                "Fix: give the camera offset, e.g. --baseline 100."
            )
        if not (math.isfinite(self.gain_adu_per_e) and self.gain_adu_per_e > 0):
            raise ValueError(
                f"gain must be a finite number > 0 ADU per electron; got {self.gain_adu_per_e!r}. "
                "Fix: give the camera's conversion gain, e.g. --gain 0.5."
            )
        if not 0 < self.quantum_efficiency <= 1:
            raise ValueError(
                f"quantum_efficiency must be in (0, 1]; got {self.quantum_efficiency!r}. Fix: e.g. 0.8."
            )

    @property
    def volume_units(self) -> str:
        """The unit of a volume reconstructed from frames converted with this calibration."""
        return "photons per voxel" if self.gain_known else "ADU above the baseline per voxel"

    def to_dict(self) -> dict[str, Any]:
        return {
            "baseline_adu": self.baseline_adu,
            "gain_adu_per_e": self.gain_adu_per_e,
            "quantum_efficiency": self.quantum_efficiency,
            "source": self.source,
            "gain_known": self.gain_known,
        }


def camera_metadata(camera: Any, *, photons: float | None, seed: int) -> dict[str, Any]:
    """The ``"camera"`` metadata of a simulated image taken with ``camera`` (an engine ``Camera``)."""
    return {
        "baseline_adu": float(camera.baseline),
        "gain_adu_per_e": float(camera.gain),
        "quantum_efficiency": float(camera.quantum_efficiency),
        "read_noise_e": float(camera.read_noise),
        "bit_depth": int(camera.bit_depth),
        "full_well_e": None if camera.full_well is None else float(camera.full_well),
        "photons": photons,
        "seed": seed,
    }


def adu_array(counts: torch.Tensor, bit_depth: int) -> torch.Tensor:
    """Digital counts as a camera stores them: uint16 for ``bit_depth <= 16``, else float32 integers.

    ``counts`` must already be rounded and clipped to ``[0, 2^bit_depth - 1]`` (see
    :func:`lfm_studio.engine.optics.camera.digitize`); float32 holds integers exactly up to 2^24.
    """
    if bit_depth <= 16:
        return counts.detach().round().clamp(0, 2**bit_depth - 1).to(torch.int32).to(torch.uint16)
    return counts.detach().round().to(torch.float32)


def calibration_from_metadata(metadata: dict[str, Any] | None) -> CameraCalibration | None:
    """The calibration recorded by ``lfm-studio image``, or None when the image does not carry one."""
    metadata = metadata or {}
    if metadata.get("units") == PHOTONS:
        return CameraCalibration(source="noise-free image")
    camera = metadata.get("camera")
    if not isinstance(camera, dict):
        return None
    try:
        return CameraCalibration(
            float(camera["baseline_adu"]),
            float(camera["gain_adu_per_e"]),
            float(camera.get("quantum_efficiency", 1.0)),
            source="image metadata",
        )
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(
            f"the image's camera metadata is incomplete or invalid ({error}): {camera!r}. "
            "Fix: pass --baseline and --gain."
        ) from error


def estimate_baseline(frames: torch.Tensor, percentile: float = BASELINE_PERCENTILE) -> float:
    """The camera offset (ADU) estimated as the ``percentile`` % darkest value of ``frames``.

    Light-field images are mostly dark, so the low percentiles sit at the baseline
    (minus a little read noise); a frame with no dark pixel gives an overestimate,
    which is why the caller warns and names the option that sets it.
    """
    values = frames.detach().reshape(-1).double()
    values = values[torch.isfinite(values)]  # NaN/Inf pixels are refused later, by name
    if values.numel() == 0:
        return 0.0
    if values.numel() > 1 << 22:  # a regular subsample is enough for a percentile
        values = values[:: values.numel() // (1 << 22) + 1]
    return max(float(torch.quantile(values, percentile / 100.0)), 0.0)


def resolve_calibration(
    metadata: dict[str, Any] | None,
    frames: torch.Tensor,
    *,
    baseline: float | None = None,
    gain: float | None = None,
) -> tuple[CameraCalibration, list[str]]:
    """The calibration to use for ``frames`` and the warnings to show.

    ``baseline``/``gain`` (ADU, ADU per electron) given by the user win over the
    metadata; without both, a missing baseline is estimated and a missing gain is 1
    (the volume is then in ADU above the baseline, not photons), each with a warning.
    """
    recorded = calibration_from_metadata(metadata)
    if baseline is None and gain is None and recorded is not None:
        return recorded, []
    notes: list[str] = []
    qe = recorded.quantum_efficiency if recorded is not None else 1.0
    if baseline is None:
        if recorded is not None:
            baseline = recorded.baseline_adu
        else:
            baseline = estimate_baseline(frames)
            notes.append(
                f"the image has no camera metadata; estimated the baseline as {baseline:.6g} ADU "
                f"(the darkest {BASELINE_PERCENTILE:g} % of the pixels). Fix: pass --baseline ADU if you know it."
            )
    gain_known = True
    if gain is None:
        if recorded is not None:
            gain = recorded.gain_adu_per_e
        else:
            gain, gain_known = 1.0, False
            notes.append(
                "the image has no camera gain; taking 1 ADU per electron, so the volume is in counts above "
                "the baseline, not photons. Fix: pass --gain ADU_PER_ELECTRON for photons per voxel."
            )
    source = "estimated" if notes else "--baseline/--gain"
    return CameraCalibration(float(baseline), float(gain), qe, source=source, gain_known=gain_known), notes


def counts_to_photons(frames: torch.Tensor, calibration: CameraCalibration, *, name: str) -> torch.Tensor:
    """Photons at the camera per pixel from counts: ``max(ADU - baseline, 0) / gain / QE``.

    ``name`` (the file or layer) is named when ``frames`` holds NaN/Inf values, which no
    camera writes: that is refused rather than propagated into the reconstruction.
    """
    if frames.is_complex():
        raise ValueError(f"{name} is complex ({frames.dtype}); a camera image is real. Fix: save |x|^2.")
    finite = torch.isfinite(frames)
    if not bool(finite.all()):
        bad = int((~finite).sum())
        raise ValueError(
            f"{name} has {bad} NaN/Inf pixel(s) of {frames.numel()}; a camera writes finite counts. "
            "Fix: replace them (e.g. with the baseline) or mask the bad pixels before reconstructing."
        )
    scale = calibration.gain_adu_per_e * calibration.quantum_efficiency
    return (frames - calibration.baseline_adu).clamp_min(0.0) / scale
