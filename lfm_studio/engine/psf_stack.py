"""``PSFStack``: the point responses of one optical system per depth, with their sampling and origin.

Two layouts share the class:

- per-depth PSFs of a laterally shift-invariant system (Fourier LFM, a measured bead
  stack): ``data`` of shape ``(..., Z, Y, X)``, the camera-plane intensity of a unit
  point source at each depth, and ``patterns`` is ``None``;
- the lenslet patterns of a conventional LFM (not shift-invariant; periodic in the
  lenslet lattice): ``data`` of shape ``(S, S, Z, H, H)``, one pattern per voxel
  sub-position and depth, described by the typed :class:`ConventionalPatterns`.

The stack knows its depths (sample side), the sensor pixel pitch, the lateral
magnification from sample to sensor and, when it was simulated, the design that produced it.
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
class ConventionalPatterns:
    """The layout of a conventional-LFM pattern stack (data ``(S, S, Z, H, H)``).

    Attributes
    ----------
    pixels_per_lenslet : ``Q``, rectified sensor pixels per lenslet per axis (odd).
    voxels_per_lenslet : ``S``, volume voxels per lenslet pitch per axis (odd).
    reach : per depth, the lenslets ``R`` on each side of the source's lenslet that its
        light reaches; depth ``z``'s pattern is the centred ``(2 R + 3) Q`` square of the
        ``H x H`` canvas (narrower patterns are zero-padded).
    lenslets : ``(Ly, Lx)`` lenslets imaged (the rectified sensor is ``(Ly Q, Lx Q)`` pixels).
    """

    pixels_per_lenslet: int
    voxels_per_lenslet: int
    reach: tuple[int, ...]
    lenslets: tuple[int, int]

    def __post_init__(self) -> None:
        for name in ("pixels_per_lenslet", "voxels_per_lenslet"):
            value = getattr(self, name)
            if isinstance(value, bool) or int(value) != value or value < 1 or value % 2 == 0:
                raise ValueError(f"ConventionalPatterns.{name} must be an odd integer >= 1; got {value!r}.")
            object.__setattr__(self, name, int(value))
        reach = tuple(int(r) for r in self.reach)
        if not reach or any(r < 0 or r != q for r, q in zip(reach, self.reach, strict=True)):
            raise ValueError(
                f"ConventionalPatterns.reach must list one integer >= 0 per depth; got {self.reach!r}."
            )
        object.__setattr__(self, "reach", reach)
        lenslets = tuple(int(n) for n in self.lenslets)
        if len(lenslets) != 2 or min(lenslets) < 1 or lenslets != tuple(self.lenslets):
            raise ValueError(
                f"ConventionalPatterns.lenslets must be two positive integers (Ly, Lx); got {self.lenslets!r}."
            )
        object.__setattr__(self, "lenslets", lenslets)

    def width(self, depth_index: int) -> int:
        """Side ``(2 R + 3) Q`` in pixels of depth ``depth_index``'s pattern."""
        return (2 * self.reach[depth_index] + 3) * self.pixels_per_lenslet

    def check_data(self, data: torch.Tensor) -> None:
        """Raise unless ``data`` is ``(S, S, Z, H, H)`` with ``H`` at least every depth's width."""
        s, z = self.voxels_per_lenslet, len(self.reach)
        shape = tuple(data.shape)
        widest = max(self.width(i) for i in range(z))
        if (
            len(shape) != 5
            or shape[:3] != (s, s, z)
            or shape[3] != shape[4]
            or shape[3] < widest
            or (shape[3] - widest) % 2
        ):
            raise ValueError(
                f"conventional pattern data must have shape (S, S, Z, H, H) = ({s}, {s}, {z}, H, H) with "
                f"H >= {widest} (the widest reach) and H - {widest} even; got {shape}. Fix: keep the data "
                "from conventional_psf_stack, or drop the patterns (patterns=None) for a shift-invariant stack."
            )


@dataclass(frozen=True)
class PSFStack:
    """The point responses of one optical system, per depth (module docstring: two layouts).

    Attributes
    ----------
    data : real tensor, shape ``(..., Z, Y, X)`` (``(S, S, Z, H, H)`` with ``patterns``)
        Non-negative camera-plane intensity of a unit point source per depth (per voxel
        sub-position for conventional patterns).
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
        Free-form JSON-serialisable provenance (e.g. bead measurement notes); never read
        to build a projector.
    patterns : ConventionalPatterns or None
        The lenslet-pattern layout of a conventional-LFM stack; ``None`` for per-depth
        shift-invariant PSFs.
    volume_oversampling : int
        ``k`` (odd, >= 1): the PSFs are sampled on a virtual sensor ``k`` times finer than the
        camera (``pixel_size`` is the virtual pitch); their projector sums ``k x k`` virtual
        pixels onto each camera pixel. 1 for camera-sampled PSFs and for lenslet patterns.
    """

    data: torch.Tensor
    depths: Depths
    pixel_size: float
    magnification: float
    wavelength: float
    design: Design | dict[str, JSONValue] | None = None
    metadata: dict[str, JSONValue] = field(default_factory=dict)
    patterns: ConventionalPatterns | None = None
    volume_oversampling: int = 1

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
        if self.data.device.type != "meta":  # (a meta tensor has a shape but no values to check)
            require_finite_tensor("PSFStack.data", self.data.detach())
            if self.data.numel() and float(self.data.detach().min()) < 0:
                raise ValueError("PSFStack.data must be non-negative (intensities). Fix: clip or re-measure.")
        if self.patterns is not None:
            if not isinstance(self.patterns, ConventionalPatterns):
                raise TypeError(
                    f"PSFStack.patterns must be a ConventionalPatterns or None; got {type(self.patterns).__name__}."
                )
            self.patterns.check_data(self.data)
        k = self.volume_oversampling
        if isinstance(k, bool) or int(k) != k or k < 1 or k % 2 == 0:
            raise ValueError(
                f"PSFStack.volume_oversampling must be an odd integer >= 1 (virtual pixels per camera "
                f"pixel); got {k!r}."
            )
        object.__setattr__(self, "volume_oversampling", int(k))
        if k > 1 and self.patterns is not None:
            raise ValueError(
                "PSFStack.volume_oversampling > 1 applies to shift-invariant PSFs, not to conventional "
                "lenslet patterns (their voxels per lenslet set the volume grid). Fix: leave it at 1."
            )

    @property
    def shift_invariant(self) -> bool:
        """Whether the stack holds per-depth shift-invariant PSFs (not conventional lenslet patterns)."""
        return self.patterns is None

    @property
    def object_pixel_size(self) -> float:
        """Lateral pixel size projected into the sample, in metres."""
        return self.pixel_size / self.magnification

    @property
    def camera_pixel_size(self) -> float:
        """Camera pixel pitch in metres: ``pixel_size`` times ``volume_oversampling``."""
        return self.pixel_size * self.volume_oversampling

    @property
    def camera_shape(self) -> tuple[int, int]:
        """``(ny, nx)`` camera pixels the PSFs cover: the sensor, or the whole ``k x k`` blocks of a
        virtual sensor ``k`` times finer (lenslet patterns: the pattern canvas)."""
        ny, nx = self.data.shape[-2:]
        k = self.volume_oversampling
        return (ny // k, nx // k)

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
