"""What a viewer draws over the radiometry frame to show whether a calibration fits.

:func:`grid_overlay` gives, per lenslet (conventional) or sub-image (Fourier), the point the
model puts it at (the fitted lattice site, or the registered design centre), the measured
centroid, the residual and the flag names, so a viewer (the napari Calibrate widget, the
studio) can draw fitted points, measured points and flagged ones in another colour.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lfm_studio.engine.calibration.grid_fit import FLAG_NAMES
from lfm_studio.engine.calibration.record import Calibration


@dataclass(frozen=True)
class GridOverlay:
    """Points to draw over the radiometry frame, (y, x) px.

    Attributes
    ----------
    fitted : (L, 2) where the fitted model puts each lenslet / sub-image.
    measured : (L, 2) measured centroids.
    residual : (L,) px.
    flags : per point, the names of its flags ("edge", "dim", "residual"); empty when used.
    """

    fitted: torch.Tensor
    measured: torch.Tensor
    residual: torch.Tensor
    flags: tuple[tuple[str, ...], ...]


def _names(bits: torch.Tensor) -> tuple[tuple[str, ...], ...]:
    return tuple(tuple(name for bit, name in FLAG_NAMES.items() if value & bit) for value in bits.tolist())


def grid_overlay(calibration: Calibration) -> GridOverlay:
    """The overlay of ``calibration`` (see the module docstring)."""
    if calibration.grid is not None:
        grid = calibration.grid
        fitted = grid.lattice.centres(grid.indices)
        return GridOverlay(fitted, grid.measured.clone(), grid.residual.clone(), _names(grid.flags))
    fit = calibration.sub_images
    if fit is None:  # excluded by Calibration.__post_init__
        raise ValueError("a calibration holds a lattice fit or a sub-image fit.")
    return GridOverlay(fit.registered(), fit.measured.clone(), fit.residual.clone(), _names(fit.flags))
