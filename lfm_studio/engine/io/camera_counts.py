"""Camera counts (ADU) <-> photons: the camera metadata an image carries, and the conversion back.

``lfm-studio image`` writes what a real camera writes, integer ADU (uint16 for a bit
depth <= 16), and records in the image metadata (key ``"camera"``) what is needed to
undo the camera::

    {"baseline_adu": 100.0, "gain_adu_per_e": 2.0, "quantum_efficiency": 0.8,
     "read_noise_e": 1.5, "bit_depth": 16, "full_well_e": 30000.0,
     "photons": 1e6, "seed": 1}

with ``"units": "ADU"``. Reconstruction turns counts back into photons at the camera,

    photons = max((ADU - baseline) / gain + c, 0) / QE,  background c / QE per pixel

(gain in ADU per electron). ``c`` is the camera's noise floor (:attr:`CameraCalibration.
noise_floor_e`: ``max(s^2, 3 s)`` electrons with ``s^2`` = read noise^2 + ADC rounding
``1 / (12 gain^2)``): read noise scatters dark pixels below the baseline, and clipping
them at 0 would add ``0.4 s`` of fake light to every pixel (on a 2048^2 sensor more than
the whole signal of 1e6 photons; accelerated RL then collapsed to an all-zero volume).
Shifted by ``c``, almost no pixel is clipped and Richardson-Lucy models ``c`` as a known
background (Snyder et al. 1993 shift by ``s^2``; ``3 s`` keeps the clipping bias below
1e-3 s per pixel). A volume reconstructed from them is in photons per voxel, the unit of
the ground truth that ``image --truth`` writes: the volume that, projected through the
PSF stack, gives the expected photons at the camera (per bead, the photons it emits in
the PSF's normalisation). A TIFF without this metadata (a measured camera frame) gets
the baseline and gain from the caller, or else a baseline estimated from the darkest
pixels (:func:`estimate_baseline`) with a warning that names the estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Protocol

import torch

from lfm_studio.engine.errors import as_real_tensor
from lfm_studio.engine.types import TensorLike

#: Percentile of the frame taken as the baseline when nothing gives it (the darkest 1 %).
BASELINE_PERCENTILE = 1.0
#: The noise floor is at least this many read-noise sigmas (clipping bias < 1e-3 sigma per pixel).
NOISE_FLOOR_SIGMAS = 3.0
#: The ``units`` of an image in camera counts; a noise-free image is already in photons.
ADU, PHOTONS = "ADU", "photons"


@dataclass(frozen=True)
class CameraCalibration:
    """How to undo a camera: ``photons = max((ADU - baseline_adu) / gain_adu_per_e + c, 0) / quantum_efficiency``
    with ``c`` = :attr:`noise_floor_e` modelled as background.

    ``read_noise_e`` (electrons rms, 0 when unknown) and ``quantized`` (integer ADC counts;
    False for a noise-free image) set the noise floor. ``source`` says where the values
    came from (shown to the user): ``"image metadata"``, ``"--baseline/--gain"``,
    ``"estimated"`` or ``"noise-free image"``; ``gain_known`` is False when the gain was
    assumed (the result is then in ADU above the baseline).
    """

    baseline_adu: float = 0.0
    gain_adu_per_e: float = 1.0
    quantum_efficiency: float = 1.0
    source: str = "image metadata"
    gain_known: bool = True
    read_noise_e: float = 0.0
    quantized: bool = True

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
        if not (math.isfinite(self.read_noise_e) and self.read_noise_e >= 0):
            raise ValueError(f"read_noise_e must be a finite number >= 0 e- rms; got {self.read_noise_e!r}.")
        if not 0 < self.quantum_efficiency <= 1:
            raise ValueError(
                f"quantum_efficiency must be in (0, 1]; got {self.quantum_efficiency!r}. Fix: e.g. 0.8."
            )

    @property
    def noise_floor_e(self) -> float:
        """Electrons added to every pixel before clipping at 0 (and modelled as background):
        ``max(s^2, 3 s)`` with ``s^2 = read_noise^2 + 1 / (12 gain^2)`` (ADC rounding); 0 without noise."""
        variance = self.read_noise_e**2 + (1.0 / (12.0 * self.gain_adu_per_e**2) if self.quantized else 0.0)
        return max(variance, NOISE_FLOOR_SIGMAS * math.sqrt(variance))

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
            "read_noise_e": self.read_noise_e,
            "noise_floor_e": self.noise_floor_e,
        }


class CameraSettings(Protocol):
    """What undoing a camera needs of a design's camera (``Design.camera``, a ``CameraSpec``)."""

    @property
    def baseline_adu(self) -> float: ...
    @property
    def gain_adu_per_e(self) -> float: ...
    @property
    def quantum_efficiency(self) -> float: ...
    @property
    def read_noise_e(self) -> float: ...


def design_camera(camera: CameraSettings, source: str = "the design's camera") -> CameraCalibration:
    """The :class:`CameraCalibration` that undoes a design's camera (``design.camera``): its
    baseline (ADU), gain (ADU per electron), quantum efficiency and read noise (electrons rms), as
    they are; ``source`` names it in messages."""
    return CameraCalibration(
        baseline_adu=camera.baseline_adu,
        gain_adu_per_e=camera.gain_adu_per_e,
        quantum_efficiency=camera.quantum_efficiency,
        source=source,
        read_noise_e=camera.read_noise_e,
    )


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
        return CameraCalibration(source="noise-free image", quantized=False)
    camera = metadata.get("camera")
    if not isinstance(camera, dict):
        return None
    try:
        return CameraCalibration(
            float(camera["baseline_adu"]),
            float(camera["gain_adu_per_e"]),
            float(camera.get("quantum_efficiency", 1.0)),
            source="image metadata",
            read_noise_e=float(camera.get("read_noise_e") or 0.0),
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
    read_noise: float | None = None,
    quantum_efficiency: float | None = None,
) -> tuple[CameraCalibration, list[str]]:
    """The calibration to use for ``frames`` and the warnings to show.

    ``baseline``/``gain``/``read_noise``/``quantum_efficiency`` (ADU, ADU per electron,
    electrons rms, photo-electrons per photon in (0, 1]) given by the user win over the
    metadata; without both, a missing baseline is estimated and a missing gain is 1 (the
    volume is then in ADU above the baseline, not photons), each with a warning; a missing
    read noise is the metadata's, else 0 (the ADC rounding still counts); a missing quantum
    efficiency is the metadata's, else 1 (the volume then counts photo-electrons).
    """
    recorded = calibration_from_metadata(metadata)
    if recorded is not None and read_noise is not None:
        recorded = replace(recorded, read_noise_e=float(read_noise))
    if recorded is not None and quantum_efficiency is not None:
        recorded = replace(recorded, quantum_efficiency=float(quantum_efficiency))
    if baseline is None and gain is None and recorded is not None:
        return recorded, []
    notes: list[str] = []
    if recorded is not None:
        qe = recorded.quantum_efficiency  # the user's, when given (replaced above)
    else:
        qe = 1.0 if quantum_efficiency is None else quantum_efficiency
    if read_noise is None:
        read_noise = recorded.read_noise_e if recorded is not None else 0.0
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
    calibration = CameraCalibration(
        float(baseline), float(gain), float(qe), source=source, gain_known=gain_known, read_noise_e=float(read_noise),
        quantized=recorded.quantized if recorded is not None else True,  # a noise-free image stays unrounded
    )  # fmt: skip
    return calibration, notes


def counts_to_photons(
    frames: TensorLike, calibration: CameraCalibration, *, name: str
) -> tuple[torch.Tensor, float]:
    """Photons at the camera per pixel from counts, and the background they carry.

    Returns ``(max((ADU - baseline) / gain + c, 0) / QE, c / QE)`` with ``c`` the noise floor
    (:attr:`CameraCalibration.noise_floor_e`): pass the second value as (part of) the
    reconstruction's background. ``frames`` is a tensor or an array (numpy, e.g. ``uint16``
    counts), taken in its floating dtype (float32 for integer counts) on its device.
    ``name`` (the file or layer) is named when ``frames`` holds NaN/Inf values, which no
    camera writes: that is refused rather than propagated into the reconstruction.
    """
    frames = torch.as_tensor(frames)
    if frames.is_complex():
        raise ValueError(f"{name} is complex ({frames.dtype}); a camera image is real. Fix: save |x|^2.")
    real = frames.dtype if frames.is_floating_point() else torch.float32
    frames = as_real_tensor(name, frames, dtype=real, device=frames.device)
    finite = torch.isfinite(frames)
    if not bool(finite.all()):
        bad = int((~finite).sum())
        raise ValueError(
            f"{name} has {bad} NaN/Inf pixel(s) of {frames.numel()}; a camera writes finite counts. "
            "Fix: replace them (e.g. with the baseline) or mask the bad pixels before reconstructing."
        )
    floor = calibration.noise_floor_e
    electrons = (frames - calibration.baseline_adu) / calibration.gain_adu_per_e
    qe = calibration.quantum_efficiency
    return (electrons + floor).clamp_min(0.0) / qe, floor / qe
