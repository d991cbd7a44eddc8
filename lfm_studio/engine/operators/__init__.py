"""Forward projection ``A`` (volume -> camera image) and its exact adjoint ``A^T``."""

from lfm_studio.engine.operators.shift_invariant import ShiftInvariantProjector

__all__ = ["ShiftInvariantProjector"]
