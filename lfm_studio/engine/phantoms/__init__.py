"""Synthetic ground-truth volumes with a seed: beads, cells in a brain-sized ellipsoid, TIFFs.

Every generator takes an explicit ``seed`` (int or CPU ``torch.Generator``): same seed,
same volume, on every device. Volumes are ``(Z, Y, X)`` tensors (float32 by default)
inside a :class:`Phantom` that also lists what was placed where.

Example::

    from lfm_studio.engine.phantoms import beads, cells_in_ellipsoid
    from lfm_studio.engine.units import um

    gt = beads((64, 128, 128), count=50, voxel_size=(2 * um, 1 * um, 1 * um), seed=0)
    gt.data, gt.positions, gt.indices          # volume, centres (m), peak voxels
    brain = cells_in_ellipsoid(voxel_size=(2 * um,) * 3, seed=0)   # larval zebrafish brain, ~42k cells
"""

from lfm_studio.engine.phantoms.beads import DEFAULT_BEADS, beads, default_bead_count
from lfm_studio.engine.phantoms.cells import (
    DEFAULT_CELL_DENSITY,
    ZEBRAFISH_BRAIN_SEMI_AXES,
    cells_in_ellipsoid,
)
from lfm_studio.engine.phantoms.from_file import from_tiff
from lfm_studio.engine.phantoms.phantom import Phantom
from lfm_studio.engine.phantoms.placement import PlacementError

__all__ = [
    "DEFAULT_BEADS",
    "DEFAULT_CELL_DENSITY",
    "ZEBRAFISH_BRAIN_SEMI_AXES",
    "Phantom",
    "PlacementError",
    "beads",
    "cells_in_ellipsoid",
    "default_bead_count",
    "from_tiff",
]
