"""Phase masks: SLM or diffuser, thesis eq. 3.19 ``U = U' exp(j phi(x, y))``.

:func:`apply_phase` is the pure function; :class:`PhaseMask` is a thin
``torch.nn.Module`` holding the phase, trainable (``nn.Parameter``) or fixed
(buffer) as chosen at construction, with the optional behaviour of a real SLM:
wrapping to ``[0, 2 pi)`` and quantisation to ``levels`` grey levels.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from lfm_studio.engine.errors import require_finite_tensor
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid

TWO_PI = 2.0 * math.pi


def apply_phase(field: Field, phase: torch.Tensor | float) -> Field:
    """Multiply ``field`` by ``exp(j phase)``.

    Parameters
    ----------
    field : Field, data ``(..., ny, nx)``
    phase : real tensor ``(..., ny, nx)`` (broadcast against the data), 0-d tensor or number
        Phase delay in radians. It is converted to float64 before the complex
        exponential, which is then cast to the field's dtype; gradients flow to it.

    Returns
    -------
    Field on the same grid.
    """
    if not isinstance(phase, torch.Tensor):
        phase = torch.tensor(float(phase), dtype=torch.float64)
    if phase.is_complex():
        raise TypeError(
            f"phase must be real (radians); got dtype {phase.dtype}. "
            "Fix: pass the phase angle, or use apply_pupil for a complex transmission."
        )
    if phase.ndim == 1 or (phase.ndim >= 2 and tuple(phase.shape[-2:]) != field.grid.shape):
        raise ValueError(
            f"phase shape {tuple(phase.shape)} does not end in the field's grid shape {field.grid.shape}. "
            "Fix: sample the phase on field.grid."
        )
    require_finite_tensor("phase", phase.detach())
    phi = phase.to(device=field.device, dtype=torch.float64)
    phasor = torch.complex(torch.cos(phi), torch.sin(phi)).to(field.dtype)
    return field.with_data(field.data * phasor)


def quantize_phase(phase: torch.Tensor, levels: int) -> torch.Tensor:
    """Wrap ``phase`` to ``[0, 2 pi)`` and round it to ``levels`` equally spaced values.

    The values are ``m * 2 pi / levels`` for ``m = 0 .. levels - 1``. The rounding
    uses a straight-through estimator: the forward value is quantised, the
    gradient is that of the identity (the wrap has derivative 1 almost
    everywhere), so a quantised mask stays trainable.
    """
    if isinstance(levels, bool) or not isinstance(levels, int) or levels < 2:
        raise ValueError(f"levels must be an integer >= 2; got {levels!r}. Fix: e.g. 256 for an 8-bit SLM.")
    step = TWO_PI / levels
    wrapped = torch.remainder(phase, TWO_PI)
    quantised = torch.remainder(torch.round(wrapped / step), levels) * step
    return wrapped + (quantised - wrapped).detach()


class PhaseMask(nn.Module):
    """A pixelated phase mask (SLM, diffuser) on a fixed grid.

    Parameters
    ----------
    grid : Grid
        Grid the mask is sampled on; fields passed to :meth:`forward` must match it.
    phase : real tensor ``(ny, nx)`` in radians, optional
        Initial phase (copied); zeros of ``dtype`` when omitted.
    trainable : bool
        ``True`` stores the phase as an ``nn.Parameter``, ``False`` as a buffer
        (moves with ``.to()``, saved in the state dict, no gradient).
    wrap : bool
        Apply ``phase mod 2 pi`` in the forward pass (as an SLM displays it).
    levels : int, optional
        Quantise the wrapped phase to ``levels`` grey levels (implies ``wrap``), with
        a straight-through gradient (:func:`quantize_phase`).
    dtype : torch dtype of the zeros when ``phase`` is omitted (float64 by default).
    """

    def __init__(
        self,
        grid: Grid,
        phase: torch.Tensor | None = None,
        *,
        trainable: bool = False,
        wrap: bool = False,
        levels: int | None = None,
        dtype: torch.dtype = torch.float64,
    ) -> None:
        super().__init__()
        if not isinstance(grid, Grid):
            raise TypeError(f"grid must be a Grid; got {type(grid).__name__}.")
        if phase is None:
            phase = torch.zeros(grid.shape, dtype=dtype)
        if not isinstance(phase, torch.Tensor) or phase.is_complex() or not phase.is_floating_point():
            raise TypeError(
                f"phase must be a real floating tensor in radians; got {getattr(phase, 'dtype', type(phase))}. "
                "Fix: pass torch.zeros(grid.shape) or the phase angle of your mask."
            )
        if tuple(phase.shape) != grid.shape:
            raise ValueError(
                f"phase shape {tuple(phase.shape)} does not match the grid shape {grid.shape}. "
                "Fix: sample the initial phase on the mask grid."
            )
        require_finite_tensor("phase", phase)
        if levels is not None:
            quantize_phase(phase[:1, :1], levels)  # validates levels early
        self.grid = grid
        self.wrap = bool(wrap) or levels is not None
        self.levels = levels
        data = phase.detach().clone()
        if trainable:
            self.phase = nn.Parameter(data)
        else:
            self.register_buffer("phase", data)

    @property
    def trainable(self) -> bool:
        return isinstance(self.phase, nn.Parameter)

    def effective_phase(self) -> torch.Tensor:
        """The phase the mask applies, after wrapping and quantisation, in radians ``(ny, nx)``."""
        if self.levels is not None:
            return quantize_phase(self.phase, self.levels)
        if self.wrap:
            return torch.remainder(self.phase, TWO_PI)
        return self.phase

    def forward(self, field: Field) -> Field:
        """Apply the mask to ``field`` (data ``(..., ny, nx)`` on this mask's grid)."""
        if not field.grid.same_as(self.grid):
            raise ValueError(
                f"PhaseMask grid {self.grid} does not match the field grid {field.grid}. "
                "Fix: build the PhaseMask on the grid of the field that reaches it (or resample the field)."
            )
        return apply_phase(field, self.effective_phase())

    def sample(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """The effective phase (rad) at arbitrary points ``x``, ``y`` (metres, same frame as the grid).

        Bilinear interpolation between the mask's sample centres (sample ``i`` at
        ``(i - n // 2) d``); beyond the outer sample centres the phase falls linearly to
        zero (no modulation) over one sample.
        At the sample centres it returns the samples exactly. Differentiable with respect
        to the phase and (piecewise) to the coordinates; float64, the broadcast shape of
        ``x`` and ``y``.
        """
        xb, yb = torch.broadcast_tensors(x.to(torch.float64), y.to(torch.float64))
        ny, nx = self.grid.shape
        dy, dx = self.grid.spacing
        # grid_sample with align_corners=True maps -1 .. 1 onto sample 0 .. n - 1.
        gx = (xb / dx + nx // 2) * (2.0 / max(nx - 1, 1)) - 1.0
        gy = (yb / dy + ny // 2) * (2.0 / max(ny - 1, 1)) - 1.0
        coords = torch.stack((gx, gy), dim=-1).reshape(1, 1, -1, 2)
        phase = self.effective_phase().to(device=xb.device, dtype=torch.float64)[None, None]
        values = torch.nn.functional.grid_sample(
            phase, coords, mode="bilinear", padding_mode="zeros", align_corners=True
        )
        return values.reshape(xb.shape)

    def extra_repr(self) -> str:
        return f"grid={self.grid}, trainable={self.trainable}, wrap={self.wrap}, levels={self.levels}"
