"""The imaging set-up a learned model trains and runs on, and the identity it records.

Training simulates the design's PSF stack (or takes one read from a file) and builds the
projector with :func:`~lfm_studio.engine.simulation.imaging_setup`, exactly as ``lfm-studio
reconstruct --psf`` does, so a checkpoint trained from a design runs on that design's PSF file.
The identity is the design's optics hash (None for a PSF without a design) and the PSF depths.
"""

from __future__ import annotations

from lfm_studio.engine.design import Design
from lfm_studio.engine.design.hashing import optics_hash
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.simulation import ImagingSetup


def stack_identity(stack: PSFStack) -> tuple[str | None, tuple[float, ...]]:
    """``(design optics hash or None, depths in m)`` of a PSF stack."""
    design = stack.design
    return (optics_hash(design) if isinstance(design, Design) else None), tuple(stack.depths)


def check_checkpoint_for_stack(path: str, stack: PSFStack, setup: ImagingSetup) -> None:
    """Refuse checkpoint ``path`` unless it was trained for ``stack``'s design, depths and ``setup``'s grid."""
    from lfm_studio.engine.learned.checkpoint import check_matches, read_checkpoint

    header, _ = read_checkpoint(path)
    design_hash, depths = stack_identity(stack)
    check_matches(header, setup.projector, path, voxel_size=setup.voxel_size, design_hash=design_hash,
                  depths=depths)  # fmt: skip
