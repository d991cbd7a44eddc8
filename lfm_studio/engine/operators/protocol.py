"""What a projector is, as typing protocols: the seam between optics and reconstruction.

:class:`Projector` is the linear forward model ``A`` (volume ``(Z, Y, X)`` -> camera image
``(Py, Px)``) with its exact adjoint ``A^T``; Richardson-Lucy and everything iterative use
only that. :class:`FourierProjector` adds what the Fourier-domain solvers (Wiener, Tikhonov,
the Wiener-Butterworth back projector) need: a laterally shift-invariant model given by
cached per-depth OTFs on a zero-padded FFT window. :class:`PrunedFourierProjector` adds the
projector's own pruned-transform back projection with arbitrary per-depth filters.

The protocols are ``runtime_checkable``: ``isinstance(x, Projector)`` checks that the members
exist (not their types; mypy checks those statically). A new projector implements them
structurally (no base class); ``tests/engine/operators/test_protocol.py`` checks every
projector of the engine against them, at run time and with mypy.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Protocol, runtime_checkable

import torch

from lfm_studio.engine.types import DepthSlice, Shape2, Shape3


@runtime_checkable
class Projector(Protocol):
    """Linear forward model ``A`` and its adjoint, in one dtype on one device."""

    @property
    def volume_shape(self) -> Shape3:
        """``(Z, Y, X)`` of the volumes :meth:`forward` accepts (voxels)."""
        ...

    @property
    def image_shape(self) -> Shape2:
        """``(Py, Px)`` of the camera images :meth:`forward` returns (pixels)."""
        ...

    @property
    def device(self) -> torch.device:
        """Where the projector's tensors live; reconstructions run there."""
        ...

    @property
    def dtype(self) -> torch.dtype:
        """Real dtype of the projector (float32 or float64); reconstructions run in it."""
        ...

    def forward(self, volume: torch.Tensor) -> torch.Tensor:
        """``A x``: volume ``(Z, Y, X)`` -> image ``(Py, Px)``."""
        ...

    def adjoint(self, image: torch.Tensor) -> torch.Tensor:
        """``A^T y``: image ``(Py, Px)`` -> volume ``(Z, Y, X)`` (the exact transpose)."""
        ...


@runtime_checkable
class FourierProjector(Projector, Protocol):
    """A laterally shift-invariant projector with cached OTFs (Fourier LFM).

    Geometry (as :class:`~lfm_studio.engine.operators.ShiftInvariantProjector` defines it):
    each depth is zero-padded into the FFT window ``fft_shape`` (top-left), convolved with its
    PSF, and the full linear convolution ``full_shape`` is cropped to the sensor, centred.
    """

    @property
    def otf(self) -> torch.Tensor:
        """PSF spectra ``(Z, Fy, Fx//2+1)`` on the FFT window (the ``rfft2`` layout), complex."""
        ...

    @property
    def fft_shape(self) -> Shape2:
        """``(Fy, Fx)``: the FFT window (at least ``full_shape``)."""
        ...

    @property
    def full_shape(self) -> Shape2:
        """``(Vy + Py - 1, Vx + Px - 1)``: the full linear convolution."""
        ...

    def depth_chunks(self) -> Iterator[DepthSlice]:
        """Depth slices processed together (cache-sized on CPU, all depths on CUDA)."""
        ...


@runtime_checkable
class PrunedFourierProjector(FourierProjector, Protocol):
    """A Fourier projector that back-projects with any per-depth filters at the cost of ``A^T``."""

    @property
    def otf_t(self) -> torch.Tensor:
        """The OTFs in the transposed, contiguous layout ``(Z, Fx//2+1, Fy)``."""
        ...

    def filtered_adjoint(self, image: torch.Tensor, filters_t: torch.Tensor) -> torch.Tensor:
        """``crop(irfft2(filters_z * rfft2(embed(y))))``: image -> volume, filters in the ``otf_t`` layout."""
        ...


def missing_members(obj: object, protocol: type) -> list[str]:
    """Names of ``protocol``'s members that ``obj`` lacks (for an error message naming them)."""
    return [name for name in protocol_members(protocol) if not hasattr(obj, name)]


def protocol_members(protocol: type) -> tuple[str, ...]:
    """The method and property names a protocol requires, in declaration order (base protocols first).

    Members declared only as bare annotations (``x: int``) are not listed: these protocols declare
    every member as a method or a read-only property.
    """
    names: list[str] = []
    for klass in reversed(protocol.__mro__):
        if getattr(klass, "_is_protocol", False) and klass is not Protocol:
            names += [n for n in vars(klass) if not n.startswith("_") and n not in names]
    return tuple(names)
