"""What every system kind provides: :class:`SystemKind`, and the :class:`ImagingSetup` it builds.

A system kind (Fourier LFM, conventional LFM, ...) owns the steps that differ between
kinds: its PSF computation from a design, the memory that needs, the projector built
from its PSF stack, its closed-form metrics (:meth:`SystemKind.closed_forms`) and its
cache policy; capability flags tell the apps what the kind supports, so no caller tests
the design-file word. The concrete kinds are :mod:`.kinds_fourier` and
:mod:`.kinds_conventional`; :mod:`.kinds` maps a design to its kind.

The closed-form formulas live in the performance package, which builds on this one (its
measured metrics compute PSFs); so a kind *names* its formula function
(:attr:`SystemKind.closed_forms_provider`, ``"module:function"``) and imports it when
asked, as the reconstruction registry names its provider modules: the import graph stays
acyclic.

Adding a kind: subclass :class:`SystemKind` in a ``kinds_<name>.py`` module, list the
object in :data:`lfm_studio.engine.systems.kinds.KINDS`, accept its word in the design
parser (``engine/design``) and name its closed forms in ``closed_forms_provider``.
"""

from __future__ import annotations

import importlib
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import ClassVar

import torch

from lfm_studio.engine.design import Design
from lfm_studio.engine.operators.protocol import Projector
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.systems.closed_form_record import ClosedFormMetrics, criterion_factor
from lfm_studio.engine.systems.fourier_psf import FourierPSFReport
from lfm_studio.engine.systems.lenslet_cache import LensletCache


@dataclass(frozen=True)
class ImagingSetup:
    """A projector with the volume grid it expects (voxel size in metres, ``(dz, dy, dx)``)."""

    projector: Projector
    volume_shape: tuple[int, int, int]
    voxel_size: tuple[float, float, float]


def depth_step(stack: PSFStack) -> float:
    """Axial voxel size in metres: the first depth step, or the lateral sample-side pixel for one depth."""
    depths = stack.depths
    return abs(depths[1] - depths[0]) if len(depths) > 1 else stack.object_pixel_size


class SystemKind(ABC):
    """One kind of light-field microscope: how its PSF is computed and how it projects.

    Class attributes (capabilities)
    -------------------------------
    name : the design-file word (``design.kind``); only :mod:`.kinds` interprets it.
    title : short human name, e.g. ``"Fourier LFM"``.
    label : one line on where the MLA sits (the studio's design header).
    shift_invariant : its PSF stack holds one laterally shift-invariant PSF per depth, so
        FFT methods (Wiener, Tikhonov) and PSF-measured resolution apply; otherwise the
        stack holds lenslet patterns and only iterative methods (Richardson-Lucy) do.
    lenslet_cache : a per-lenslet :class:`LensletCache` speeds up recomputing its PSF after
        a lenslet edit (the cache is ignored when False).
    binnable_sensor : a 2 x 2-binned camera keeps its PSF's geometry (cheap previews of big sensors).
    mla_at_pupil : the MLA sits on the relayed objective pupil, each lenslet forming its own
        sub-image (Fourier LFM): lenslets must lie inside the pupil and sub-images on the sensor,
        without overlap (the optimiser's default constraints).
    pattern_axes : names of the leading PSF axes the viewer steps through (empty: plain
        ``(Z, Y, X)`` PSF slices).
    closed_forms_provider : ``"module:function"`` of its closed-form formulas,
        ``f(design, *, criterion) -> ClosedFormMetrics`` (see :meth:`closed_forms`).
    """

    name: ClassVar[str]
    title: ClassVar[str]
    label: ClassVar[str]
    shift_invariant: ClassVar[bool]
    lenslet_cache: ClassVar[bool]
    binnable_sensor: ClassVar[bool]
    mla_at_pupil: ClassVar[bool]
    pattern_axes: ClassVar[tuple[str, ...]] = ()
    closed_forms_provider: ClassVar[str]

    @abstractmethod
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
        """The PSF stack of ``design`` at ``depths`` (metres) with the design attached.

        ``dtype`` overrides the accuracy's real dtype; ``crop`` keeps about ``crop x crop``
        camera pixels around the axis; ``cache`` is used when :attr:`lenslet_cache`;
        ``report`` records the method and the lenslets computed / cached.
        """

    @abstractmethod
    def psf_bytes(self, design: Design, depth_count: int, sensor: tuple[int, int], real: torch.dtype) -> int:
        """Lower bound in bytes of what :meth:`psf_stack` holds at once for ``depth_count`` depths
        on a ``sensor`` of camera pixels, in real dtype ``real`` (complex fields of the matching width)."""

    @abstractmethod
    def image_shape(self, design: Design, *, crop: int | None = None) -> tuple[int, int]:
        """``(Py, Px)``: the camera image (pixels) the projector of ``psf_stack(design, ..., crop=crop)``
        images, from the design alone (no PSF computed): what frames must match before the set-up."""

    @abstractmethod
    def imaging_setup(self, stack: PSFStack, *, field_of_view: float | None = None) -> ImagingSetup:
        """The projector of ``stack`` (on its device and dtype) and the volume grid it expects."""

    def closed_forms(self, design: Design, *, criterion: str = "rayleigh") -> ClosedFormMetrics:
        """The closed-form metrics of ``design`` (a design of this kind), lateral resolution by
        ``criterion`` ("rayleigh", "abbe" or "sparrow"); ValueError for another kind's design."""
        criterion_factor(criterion)
        metrics: ClosedFormMetrics = self.closed_forms_formula()(design, criterion=criterion)
        return metrics

    def closed_forms_formula(self) -> Callable[..., ClosedFormMetrics]:
        """The function :attr:`closed_forms_provider` names, ``f(design, *, criterion)`` (imported now)."""
        module, function = self.closed_forms_provider.split(":")
        formula: Callable[..., ClosedFormMetrics] = getattr(importlib.import_module(module), function)
        return formula

    def __repr__(self) -> str:
        return f"<system kind {self.name!r}>"
