"""Checks on the frames given to a calibration; each error names the input, its value and a fix."""

from __future__ import annotations

import torch

from lfm_studio.engine.design import CameraSpec
from lfm_studio.engine.errors import require_finite_tensor

#: Largest fraction of pixels allowed at the camera's saturation level.
MAX_SATURATED_FRACTION = 0.005
#: Largest relative difference between the measured and the design's lenslet pitch.
MAX_PITCH_DEVIATION = 0.10


def as_frame(name: str, frame: object) -> torch.Tensor:
    """``frame`` (tensor or array, (Y, X)) as a finite float64 CPU tensor, or a named ``ValueError``."""
    data = torch.as_tensor(frame)
    if data.is_complex() or data.dtype == torch.bool:
        raise ValueError(f"{name} must be a real camera frame; got dtype {data.dtype}.")
    if data.ndim != 2:
        raise ValueError(
            f"{name} must be one 2D camera frame (Y, X); got shape {tuple(data.shape)}. "
            "Fix: average a stack into one frame first (e.g. in Fiji: Image > Stacks > Z Project > Average)."
        )
    data = data.to(device="cpu", dtype=torch.float64)  # calibration runs on the CPU
    require_finite_tensor(name, data)
    return data


def saturation_level(camera: CameraSpec) -> float:
    """ADU at which the camera saturates: the ADC's top or the full well, whichever comes first."""
    top = 2.0**camera.bit_depth - 1.0
    if camera.full_well_e is None:
        return top
    return min(top, camera.baseline_adu + camera.full_well_e * camera.gain_adu_per_e)


def check_frames(radiometry: torch.Tensor, dark: torch.Tensor | None, camera: CameraSpec) -> None:
    """Raise ``ValueError`` for mismatched shapes, a saturated radiometry frame or a swapped dark frame.

    Saturated: over :data:`MAX_SATURATED_FRACTION` of the pixels at the camera's saturation
    level, or piled up at the frame's maximum value (a clipped histogram, whatever the
    design's camera says).
    """
    if dark is not None and dark.shape != radiometry.shape:
        raise ValueError(
            f"dark frame shape {tuple(dark.shape)} differs from the radiometry frame's "
            f"{tuple(radiometry.shape)}. Fix: record both with the same camera region (ROI) and binning."
        )
    level = saturation_level(camera)
    fraction = float((radiometry >= level).double().mean())
    if fraction <= MAX_SATURATED_FRACTION and _piled_up_at_top(radiometry):
        level = float(radiometry.max())  # clipped at a level the design's camera does not know
        fraction = float((radiometry == level).double().mean())
    if fraction > MAX_SATURATED_FRACTION:
        raise ValueError(
            f"radiometry frame is saturated: {100 * fraction:.2g} % of its pixels reach the camera's "
            f"saturation level {level:.6g} ADU (allowed: {100 * MAX_SATURATED_FRACTION:.2g} %). "
            "Fix: record it again with a shorter exposure or weaker illumination (aim for about half the full well)."
        )
    if dark is not None and float(dark.mean()) >= float(radiometry.mean()):
        raise ValueError(
            f"dark frame (mean {float(dark.mean()):.6g} ADU) is not darker than the radiometry frame "
            f"(mean {float(radiometry.mean()):.6g} ADU). Fix: check that --dark and --radiometry are not "
            "swapped and that the dark frame was recorded with the light path blocked."
        )


def _piled_up_at_top(frame: torch.Tensor) -> bool:
    """True when over :data:`MAX_SATURATED_FRACTION` of the pixels share the maximum value and
    that value holds over 3x the pixels of the next lower one (a clipped histogram)."""
    top = frame.max()
    at_top = int((frame == top).sum())
    if at_top <= MAX_SATURATED_FRACTION * frame.numel() or at_top == frame.numel():
        return False
    below = frame[frame < top].max()
    return at_top > 3 * int((frame == below).sum())


def check_pitch(measured: tuple[float, float], nominal: float) -> None:
    """Raise ``ValueError`` when a measured pitch is far from the design's."""
    worst = max(measured, key=lambda p: abs(p - nominal))
    if abs(worst - nominal) > MAX_PITCH_DEVIATION * nominal:
        raise ValueError(
            f"lenslet grid far from the design: measured pitch {measured[0]:.4g} x {measured[1]:.4g} px, "
            f"the design predicts {nominal:.4g} px (MLA pitch_um / camera pixel_pitch_um; allowed "
            f"+-{100 * MAX_PITCH_DEVIATION:.0f} %). Fix: check the design's MLA pitch, camera pixel size and "
            "binning, and any relay magnification between the MLA and the camera."
        )
