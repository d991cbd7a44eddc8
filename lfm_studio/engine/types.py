"""Type aliases shared across the engine's seams (operators, reconstruction, simulation).

Aliases only (no runtime behaviour): they name what a tuple or union *means*, so a
signature reads ``volume_shape: Shape3`` instead of ``tuple[int, int, int]`` and mypy
checks every seam against the same definitions.
"""

from __future__ import annotations

from typing import TypeAlias

import numpy as np
import numpy.typing as npt
import torch

#: Source depths in metres, sample side, relative to the native focal plane.
Depths: TypeAlias = tuple[float, ...]
#: A lateral shape ``(Y, X)`` in pixels or voxels.
Shape2: TypeAlias = tuple[int, int]
#: A volume shape ``(Z, Y, X)`` in voxels.
Shape3: TypeAlias = tuple[int, int, int]
#: Where tensors live: a ``torch.device`` or its name (``"cpu"``, ``"cuda:0"``).
DeviceLike: TypeAlias = torch.device | str
#: A real number or a 0-d / broadcastable tensor (e.g. a background level in counts).
Scalar: TypeAlias = float | torch.Tensor
#: Image or volume data a user may hand in: a tensor or anything numpy can turn into an array
#: (checked, real and finite, and converted with :func:`torch.as_tensor` at the seam).
TensorLike: TypeAlias = torch.Tensor | npt.ArrayLike
#: A numpy array of any dtype (camera frames as read: uint8, uint16, float32, ...).
NumpyArray: TypeAlias = "npt.NDArray[np.generic[object]]"
#: A JSON value (what provenance metadata and file headers hold).
JSONValue: TypeAlias = "str | int | float | bool | list[JSONValue] | dict[str, JSONValue] | None"
#: A contiguous run of depth indices ``start:stop`` (a chunk of a volume's ``Z`` axis).
DepthSlice: TypeAlias = "slice[int, int, int | None]"
#: The value of a reconstruction method's option (:class:`~lfm_studio.engine.reconstruct.registry.Option`).
OptionValue: TypeAlias = int | float | str | bool | None
