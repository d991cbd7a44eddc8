"""No silent wrong results: refuse a reconstruction that is all zero, constant or not finite.

Such a volume is never a reconstruction of real data; it comes from inputs that do not
belong together. :func:`check_reconstruction` is the one check the command line, the
napari plugin and the studio run on every result before showing or saving it.
"""

from __future__ import annotations

import torch

#: Relative spread (max - min) / max|v| below which a volume counts as constant (float32 rounding).
CONSTANT_SPREAD = 1e-6

LIKELY_CAUSES = (
    "Likely causes: (1) the background or camera baseline is at or above the data, so nothing is left "
    "to reconstruct (check --baseline/--background: the image's dark level is the baseline); "
    "(2) the PSF stack and the image do not belong together (another design, sensor, or pixel size: "
    "use the PSF simulated for this camera); (3) the image holds no light (an all-dark frame)."
)


class ReconstructionRejectedError(ValueError):
    """A reconstruction came out all zero, constant or with NaN/Inf values; nothing was saved or shown."""


def check_reconstruction(volume: torch.Tensor, *, what: str = "the reconstruction") -> torch.Tensor:
    """Return ``volume`` if it carries information; raise :class:`ReconstructionRejectedError` if not.

    Refused: any NaN/Inf voxel, an all-zero volume, and a constant one (relative spread
    below :data:`CONSTANT_SPREAD`). ``what`` names the result in the message (e.g. ``"frame 3"``).
    """
    data = volume.detach()
    finite = torch.isfinite(data)
    if not bool(finite.all()):
        bad = int((~finite).sum())
        raise ReconstructionRejectedError(
            f"{what} has {bad} NaN/Inf voxel(s) of {data.numel()}; it was not saved. {LIKELY_CAUSES} "
            "NaN/Inf also come from NaN/Inf pixels or an overflowing --dtype float32."
        )
    peak = float(data.abs().max()) if data.numel() else 0.0
    if peak == 0.0:
        raise ReconstructionRejectedError(f"{what} is all zero; it was not saved. {LIKELY_CAUSES}")
    spread = float(data.max() - data.min())
    if spread <= CONSTANT_SPREAD * peak:
        raise ReconstructionRejectedError(
            f"{what} is constant ({float(data.reshape(-1)[0]):.6g} in every voxel); it was not saved. "
            f"{LIKELY_CAUSES}"
        )
    return volume
