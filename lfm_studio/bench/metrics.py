"""Error of a PSF stack, and of a reconstruction made with it, against the reference.

PSF error: the worst depth's relative L2 error ``max_z ||P_z - R_z|| / ||R_z||``. Both
stacks are in the engine's absolute normalisation (power per sensor pixel of a
unit-power emitter, conventional: per rectified pixel and voxel sub-position) on the
same sensor grid, so a wrong total power counts as error too; nothing is rescaled.

Reconstruction error: the same noise-free image (beads imaged with the reference
PSF) is reconstructed by Richardson-Lucy with a fixed number of iterations, once with
the reference PSF and once with the setting's; the error is
``||x_setting - x_ref|| / ||x_ref||`` over the volume.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lfm_studio.engine.operators import ShiftInvariantProjector
from lfm_studio.engine.phantoms import beads
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.reconstruct import richardson_lucy
from lfm_studio.engine.systems.conventional_psf import lattice_projector

FOURIER_VOLUME_SIDE = 63  # lateral voxels of the reconstructed volume (Fourier)
CONVENTIONAL_LENSLETS = (9, 9)  # lenslets of the reconstructed region (conventional)
BEADS = 12
ITERATIONS = 20


def psf_error(stack: torch.Tensor, reference: torch.Tensor) -> float:
    """Worst-depth relative L2 error of ``stack`` against ``reference`` (both depth first, same shape)."""
    if stack.shape != reference.shape:
        raise ValueError(
            f"stack shape {tuple(stack.shape)} differs from the reference {tuple(reference.shape)}; "
            "the error needs the same sensor grid."
        )
    diff = (stack.double() - reference.double()).flatten(1).norm(dim=1)
    return float((diff / reference.double().flatten(1).norm(dim=1)).max())


def _projector(stack: PSFStack):
    data = stack.data.detach().to("cpu", torch.float32)
    if not stack.shift_invariant:  # conventional lenslet patterns
        return lattice_projector(stack.with_data(data), CONVENTIONAL_LENSLETS)
    return ShiftInvariantProjector(data, (FOURIER_VOLUME_SIDE, FOURIER_VOLUME_SIDE))


@dataclass
class ReconstructionProbe:
    """The reference reconstruction of one case, made once and compared against each setting."""

    image: torch.Tensor
    reference: torch.Tensor
    iterations: int

    @classmethod
    def from_reference(
        cls, stack: PSFStack, *, iterations: int = ITERATIONS, seed: int = 0
    ) -> ReconstructionProbe:
        """Image ``BEADS`` seeded beads with the reference stack and reconstruct them with it."""
        projector = _projector(stack)
        shape = projector.volume_shape
        # Voxel indices only matter here: unit voxels, beads at least 2 voxels apart.
        unit = (1e-6, 1e-6, 1e-6)
        volume = beads(shape, count=BEADS, voxel_size=unit, seed=seed, margin=0.0, min_separation=2e-6).data
        image = projector.forward(volume)
        reference = richardson_lucy(projector, image, iterations=iterations)
        return cls(image, reference, iterations)

    def error(self, stack: PSFStack) -> float:
        """Relative L2 difference of the reconstruction with ``stack`` from the reference one."""
        recon = richardson_lucy(_projector(stack), self.image, iterations=self.iterations)
        return float((recon.double() - self.reference.double()).norm() / self.reference.double().norm())
