"""Forward projection ``A`` (volume -> camera image) and its exact adjoint ``A^T``.

:class:`Projector` (and the Fourier-domain :class:`FourierProjector`) are the protocols every
projector implements; the reconstruction methods accept them.
"""

from lfm_studio.engine.operators.protocol import FourierProjector, Projector, PrunedFourierProjector
from lfm_studio.engine.operators.shift_invariant import ShiftInvariantProjector

__all__ = ["FourierProjector", "Projector", "PrunedFourierProjector", "ShiftInvariantProjector"]
