"""The Fourier-LFM kind: MLA at the relayed back pupil, one shift-invariant PSF per depth.

PSF: :func:`~lfm_studio.engine.systems.fourier_psf.fourier_psf_stack` of
:func:`~lfm_studio.engine.systems.from_design.fourier_system_of` (per-lenslet, cached, or
full field). With ``accuracy.volume_oversampling`` ``k > 1`` the PSFs are sampled on a
virtual sensor ``k`` times finer (``stack.volume_oversampling``) and the
projector sums ``k x k`` virtual pixels onto each camera pixel (:class:`BinnedProjector`).
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from lfm_studio.engine.design import Design
from lfm_studio.engine.memory import tensor_bytes
from lfm_studio.engine.operators.binned import BinnedProjector
from lfm_studio.engine.operators.shift_invariant import ShiftInvariantProjector
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.systems.fourier_psf import FourierPSFReport, fourier_psf_stack
from lfm_studio.engine.systems.from_design import fourier_accuracy_of, fourier_system_of, virtual_pixel_count
from lfm_studio.engine.systems.kinds_base import ImagingSetup, Projector, SystemKind, depth_step
from lfm_studio.engine.systems.lenslet_cache import LensletCache


def complex_of(real: torch.dtype) -> torch.dtype:
    """The complex dtype of the same precision as real dtype ``real``."""
    return torch.complex128 if real == torch.float64 else torch.complex64


class FourierKind(SystemKind):
    """Fourier LFM / XLFM (:mod:`lfm_studio.engine.systems.fourier_system`)."""

    name = "fourier"
    title = "Fourier LFM"
    label = "Fourier LFM: the MLA sits at the relayed back pupil"
    shift_invariant = True
    lenslet_cache = True
    mla_at_pupil = True
    binnable_sensor = True
    closed_forms_provider = "lfm_studio.engine.performance.fourier_closed_forms:fourier_closed_forms"

    def psf_stack(
        self,
        design: Design,
        depths: tuple[float, ...],
        *,
        device: torch.device | str = "cpu",
        dtype: torch.dtype | None = None,
        crop: int | None = None,
        cache: LensletCache | None = None,
        report: FourierPSFReport | None = None,
        progress: ProgressCallback | None = None,
        cancel: CancelToken = None,
    ) -> PSFStack:
        refine = design.accuracy.volume_oversampling
        system, accuracy = fourier_system_of(design, refine=refine), fourier_accuracy_of(design)
        if crop is not None:
            ny, nx = design.camera.pixel_count
            shape = (virtual_pixel_count(min(crop, ny), refine), virtual_pixel_count(min(crop, nx), refine))
            system = replace(system, sensor_shape=shape)
        if dtype is not None:
            accuracy = replace(accuracy, dtype=dtype)
        stack = fourier_psf_stack(
            system, depths, accuracy=accuracy, device=device, cache=cache, progress=progress, cancel=cancel,
            report=report, design=design,
        )  # fmt: skip
        return replace(stack, volume_oversampling=refine)

    def image_shape(self, design: Design, *, crop: int | None = None) -> tuple[int, int]:
        """The camera's pixels, cut to ``crop`` (a finer virtual sensor is binned back onto them)."""
        ny, nx = design.camera.pixel_count
        return (ny, nx) if crop is None else (min(crop, ny), min(crop, nx))

    def psf_bytes(self, design: Design, depth_count: int, sensor: tuple[int, int], real: torch.dtype) -> int:
        """A few complex fields on the (virtual) sensor plus the ``(Z, ny, nx)`` real stack."""
        refine = design.accuracy.volume_oversampling
        shape = (sensor[0] * refine, sensor[1] * refine)
        return 3 * tensor_bytes(shape, complex_of(real)) + tensor_bytes((depth_count, *shape), real)

    def imaging_setup(self, stack: PSFStack, *, field_of_view: float | None = None) -> ImagingSetup:
        """Lateral voxel = the stack's pixel / magnification; the volume spans ``field_of_view``
        metres (default: the design's, else a quarter of the sensor), an odd number of voxels."""
        return shift_invariant_setup(stack, field_of_view=field_of_view)


def shift_invariant_lateral(stack: PSFStack, *, field_of_view: float | None = None) -> int:
    """The lateral voxel count (odd: a voxel on the optical axis) of a volume spanning
    ``field_of_view`` metres at voxel ``stack.object_pixel_size`` (metres); ``None``: the
    design's field of view, else a quarter of the (virtual) sensor's smaller side in pixels."""
    voxel = stack.object_pixel_size
    if field_of_view is None and stack.design is not None:
        field_of_view = getattr(stack.design, "field_of_view_diameter", None) or None
    ny, nx = stack.data.shape[-2:]
    lateral = min(ny, nx) // 4 if field_of_view is None else max(1, math.ceil(field_of_view / voxel))
    return lateral + 1 - lateral % 2


def shift_invariant_setup(
    stack: PSFStack, *, field_of_view: float | None = None, lateral: int | None = None
) -> ImagingSetup:
    """:class:`ShiftInvariantProjector` of ``stack`` (binned ``k x k`` for ``stack.volume_oversampling``
    ``k``), on a ``(Z, lateral, lateral)`` volume of lateral voxel ``stack.object_pixel_size``.

    ``lateral`` (voxels): fixed by the caller (e.g. an optimiser that keeps the grid of its start
    design while the magnification changes); ``None``: :func:`shift_invariant_lateral` of
    ``field_of_view`` (metres). Differentiable in ``stack.data``."""
    voxel = stack.object_pixel_size
    if lateral is None:
        lateral = shift_invariant_lateral(stack, field_of_view=field_of_view)
    projector: Projector = ShiftInvariantProjector(stack.data, (lateral, lateral))
    if stack.volume_oversampling > 1:
        projector = BinnedProjector(projector, stack.volume_oversampling)
    return ImagingSetup(projector, (len(stack.depths), lateral, lateral), (depth_step(stack), voxel, voxel))


FOURIER = FourierKind()
