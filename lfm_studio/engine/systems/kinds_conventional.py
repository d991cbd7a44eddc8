"""The conventional-LFM kind: MLA on the native image plane, lenslet patterns per depth.

PSF: :func:`~lfm_studio.engine.systems.conventional_psf.conventional_psf_stack` of
:func:`~lfm_studio.engine.systems.from_design.conventional_system_of`, a
``(S, S, Z, H, H)`` pattern stack whose layout is the typed
:class:`~lfm_studio.engine.psf_stack.ConventionalPatterns`; the projector is the
:class:`~lfm_studio.engine.operators.lenslet_lattice.LensletLatticeProjector` built from it.
Not shift-invariant: only iterative reconstruction applies. No per-lenslet cache
(every lenslet shares one pattern set).
"""

from __future__ import annotations

from dataclasses import replace

import torch

from lfm_studio.engine.design import Design, RegularMLASpec
from lfm_studio.engine.memory import tensor_bytes
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.systems.conventional_psf import conventional_psf_stack, lattice_projector
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem
from lfm_studio.engine.systems.fourier_psf import FourierPSFReport
from lfm_studio.engine.systems.from_design import conventional_accuracy_of, conventional_system_of
from lfm_studio.engine.systems.kinds_base import ImagingSetup, SystemKind, depth_step
from lfm_studio.engine.systems.kinds_fourier import complex_of
from lfm_studio.engine.systems.lenslet_cache import LensletCache

METHOD = "conventional"  # what a PSF report records as the method of this kind


class ConventionalKind(SystemKind):
    """Conventional LFM on a square lenslet lattice (:mod:`lfm_studio.engine.systems.conventional_system`)."""

    name = "conventional"
    title = "Conventional LFM"
    label = "Conventional LFM: the MLA sits at the native image plane"
    shift_invariant = False
    lenslet_cache = False
    mla_at_pupil = False
    binnable_sensor = False  # binning would change the rectified pixels per lenslet
    pattern_axes = ("sub-position row", "sub-position column")
    closed_forms_provider = (
        "lfm_studio.engine.performance.conventional_closed_forms:conventional_closed_forms"
    )

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
        """``crop``: only the lenslets that fit in ``crop`` camera pixels; ``cache`` is not used."""
        system = _system(design, crop)
        accuracy = conventional_accuracy_of(design, system)
        if dtype is not None:
            accuracy = replace(accuracy, dtype=dtype)
        if report is not None:
            report.method = METHOD
        return conventional_psf_stack(
            system, depths, accuracy=accuracy, device=device, progress=progress, cancel=cancel, design=design
        )

    def image_shape(self, design: Design, *, crop: int | None = None) -> tuple[int, int]:
        """``(Ly Q, Lx Q)`` rectified pixels of the lenslets imaged (those that fit in ``crop``)."""
        system = _system(design, crop)
        q = system.pixels_per_lenslet
        return (system.lenslets[0] * q, system.lenslets[1] * q)

    def psf_bytes(self, design: Design, depth_count: int, sensor: tuple[int, int], real: torch.dtype) -> int:
        """At least a few complex sensor-sized fields (its projector images the whole sensor)."""
        return 3 * tensor_bytes(sensor, complex_of(real))

    def imaging_setup(self, stack: PSFStack, *, field_of_view: float | None = None) -> ImagingSetup:
        """The lattice of the stack's lenslets, ``voxels_per_lenslet`` voxels per pitch
        (lateral voxel ``pixel * Q / (M S)``); ``field_of_view`` is not used (the lenslets set it)."""
        projector = lattice_projector(stack)
        layout = stack.patterns
        assert layout is not None  # (lattice_projector refuses a stack without patterns)
        voxel = (
            stack.pixel_size * layout.pixels_per_lenslet / (stack.magnification * layout.voxels_per_lenslet)
        )
        return ImagingSetup(projector, projector.volume_shape, (depth_step(stack), voxel, voxel))


def _system(design: Design, crop: int | None) -> ConventionalLFMSystem:
    """The conventional system of ``design`` imaging the lenslets that fit in ``crop`` camera pixels
    (all the sensor covers when ``crop`` is None)."""
    lenslets, mla = None, design.mla
    if crop is not None and isinstance(mla, RegularMLASpec):  # (else conventional_system_of explains)
        count = max(1, int(crop * design.camera.pixel_pitch / (mla.pitch_um * 1e-6)))
        lenslets = (min(count, mla.shape[0]), min(count, mla.shape[1]))
    return conventional_system_of(design, lenslets=lenslets)


CONVENTIONAL = ConventionalKind()
