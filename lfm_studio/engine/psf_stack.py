"""``PSFStack``: a laterally shift-invariant PSF per depth, with its sampling and origin.

The tensor is the camera-plane intensity of a unit point source at each depth
(shape ``(..., Z, Y, X)``); the stack knows its depths (sample side), the sensor
pixel pitch, the lateral magnification from sample to sensor and, when it was
simulated, the design that produced it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import torch

from lfm_studio.engine.errors import require_finite_tensor, require_positive
from lfm_studio.engine.types import Depths, JSONValue

if TYPE_CHECKING:
    from lfm_studio.engine.design import Design


@dataclass(frozen=True)
class PSFStack:
    """PSFs of one optical system, one per depth.

    Attributes
    ----------
    data : real tensor, shape ``(..., Z, Y, X)``
        Non-negative camera-plane intensity of a unit point source per depth.
    depths : tuple of float
        Source depth of each slice in metres, sample side, relative to the native
        focal plane (positive = away from the objective).
    pixel_size : float
        Sensor pixel pitch in metres.
    magnification : float
        Lateral magnification from sample to sensor; the sample-side pixel size
        is ``pixel_size / magnification``.
    wavelength : float
        Emission wavelength in metres.
    design : Design, dict or None
        The design the stack was simulated from (``None`` for a measured stack; its JSON dict when
        read from a file without rebuilding it, :func:`~lfm_studio.engine.io.read_psf_stack`).
    metadata : dict
        JSON provenance (e.g. bead measurement notes); read typed values with
        :meth:`metadata_int` / :meth:`metadata_ints`.
    """

    data: torch.Tensor
    depths: Depths
    pixel_size: float
    magnification: float
    wavelength: float
    design: Design | dict[str, JSONValue] | None = None
    metadata: dict[str, JSONValue] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.data, torch.Tensor) or self.data.is_complex() or self.data.ndim < 3:
            raise ValueError(
                "PSFStack.data must be a real tensor of shape (..., Z, Y, X); got "
                f"{getattr(self.data, 'dtype', type(self.data))} with shape {tuple(getattr(self.data, 'shape', ()))}."
            )
        object.__setattr__(self, "depths", tuple(float(z) for z in self.depths))
        if len(self.depths) != self.data.shape[-3]:
            raise ValueError(
                f"PSFStack has {self.data.shape[-3]} slices but {len(self.depths)} depths. "
                "Fix: give exactly one depth (in metres) per slice."
            )
        if not all(math.isfinite(z) for z in self.depths):
            raise ValueError(f"PSFStack depths must be finite; got {self.depths}.")
        if len(set(self.depths)) != len(self.depths):
            raise ValueError(f"PSFStack depths must be distinct; got {self.depths}.")
        require_positive("pixel_size", self.pixel_size, "m", "give the sensor pixel pitch, e.g. 6.5 * um.")
        require_positive("magnification", self.magnification, "", "give the sample-to-sensor magnification.")
        require_positive("wavelength", self.wavelength, "m", "give the emission wavelength, e.g. 525 * nm.")
        require_finite_tensor("PSFStack.data", self.data.detach())
        if self.data.numel() and float(self.data.detach().min()) < 0:
            raise ValueError("PSFStack.data must be non-negative (intensities). Fix: clip or re-measure.")

    def metadata_int(self, key: str, default: int | None = None) -> int:
        """``metadata[key]`` as an int (``default`` when absent); ``ValueError`` naming the key otherwise."""
        return _as_int(key, self.metadata.get(key, default))

    def metadata_ints(self, key: str) -> tuple[int, ...]:
        """``metadata[key]``, a list of ints, as a tuple; ``ValueError`` naming the key otherwise."""
        values = self.metadata.get(key)
        if not isinstance(values, list):
            raise ValueError(f"PSFStack.metadata[{key!r}] must be a list of integers; got {values!r}.")
        return tuple(_as_int(key, value) for value in values)

    @property
    def object_pixel_size(self) -> float:
        """Lateral pixel size projected into the sample, in metres."""
        return self.pixel_size / self.magnification

    @property
    def shape(self) -> torch.Size:
        return self.data.shape

    def depth_tensor(self, *, device: torch.device | str | None = None) -> torch.Tensor:
        """Depths as a float64 tensor of shape ``(Z,)`` in metres."""
        return torch.tensor(self.depths, dtype=torch.float64, device=device)

    def with_data(self, data: torch.Tensor, depths: tuple[float, ...] | None = None) -> PSFStack:
        """Same sampling and provenance, new data (and optionally new depths)."""
        return replace(self, data=data, depths=self.depths if depths is None else depths)

    def to(self, device: torch.device | str | None = None, dtype: torch.dtype | None = None) -> PSFStack:
        """Move to ``device`` and/or cast to a real ``dtype``."""
        return replace(self, data=self.data.to(device=device, dtype=dtype))


def _as_int(key: str, value: JSONValue) -> int:
    """A metadata value that must be an integer (a float with an integral value counts, as JSON writes it)."""
    if isinstance(value, int) and not isinstance(value, bool):
        return value
    if isinstance(value, float) and value.is_integer():
        return int(value)
    raise ValueError(
        f"PSFStack.metadata[{key!r}] must be an integer; got {value!r}. Fix: simulate the stack again "
        "(lfm_studio.engine.simulation.simulate_psf) or restore the file's metadata."
    )
