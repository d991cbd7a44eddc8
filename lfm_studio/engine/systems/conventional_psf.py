"""Conventional-LFM operator build: patterns per depth group, one pattern stack, the lattice projector."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from dataclasses import fields as dataclass_fields

import torch

from lfm_studio.engine.design import Design
from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector
from lfm_studio.engine.optics.pixel_integration import check_pixel_integration
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint
from lfm_studio.engine.psf_stack import ConventionalPatterns, PSFStack
from lfm_studio.engine.systems.conventional_patterns import (
    OUTPUT_OVERSAMPLING,
    Scalar,
    conventional_patterns,
    mirrored,
    nip_field_size,
    nip_quadrants,
)
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem
from lfm_studio.engine.threads import run_in_workers, worker_count

_MODELS = ("debye", "paraxial")


@dataclass(frozen=True)
class ConventionalAccuracy:
    """Accuracy knobs of the conventional-LFM patterns (each is benchmarked, run time against error).

    Attributes
    ----------
    dtype : ``torch.float32`` or ``torch.float64`` (fields in the matching complex dtype).
    model : objective model of the NIP field, ``"debye"`` or ``"paraxial"`` (see :func:`debye_psf`).
    debye_points : Gauss-Legendre nodes of the Debye integral; ``None`` = the engine's
        converged order for the phase excursion (:func:`debye.quadrature_order`).
    nip_oversampling : factor (>= 1) on the NIP samples per pitch (:func:`samples_per_pitch`).
    pixel_oversampling : sensor-field samples per intensity Nyquist interval before the
        pixel integration (:func:`sub_samples`; > 0).
    pixel_integration : ``"midpoint"`` (sum of the ``m x m`` sub-samples, error ``~ 1/m^2``) or
        ``"fourier"`` (exact box integral of the sampled intensity; at 3 sub-samples per pixel
        0.04-0.28 % relative L2 on 10x/0.3 patterns at 15 px per lenslet, the midpoint rule 0.4-2.8 %).
    radial_sampling : radial-table oversampling of the Debye field, or ``"exact"``.
    depth_chunk : depths per Debye NIP-field batch (bounds memory; >= 1; the patterns do not depend on it).
    """

    dtype: torch.dtype = torch.float32
    model: str = "debye"
    debye_points: int | None = None
    nip_oversampling: float = 1.0
    pixel_oversampling: float = OUTPUT_OVERSAMPLING
    pixel_integration: str = "midpoint"
    radial_sampling: int | str = 8
    depth_chunk: int = 64

    def __post_init__(self) -> None:
        if self.model not in _MODELS:
            raise ValueError(f"model must be one of {_MODELS}; got {self.model!r}. Fix: use 'debye'.")
        if self.debye_points is not None and self.debye_points < 8:
            raise ValueError(f"debye_points must be >= 8 or None; got {self.debye_points!r}. Fix: use None.")
        if not self.nip_oversampling >= 1.0:
            raise ValueError(f"nip_oversampling must be >= 1; got {self.nip_oversampling!r}. Fix: use 1.")
        if not self.pixel_oversampling > 0.0:
            raise ValueError(
                f"pixel_oversampling must be > 0; got {self.pixel_oversampling!r}. Fix: use {OUTPUT_OVERSAMPLING}."
            )
        check_pixel_integration(self.pixel_integration)
        if self.depth_chunk < 1:
            raise ValueError(f"depth_chunk must be >= 1; got {self.depth_chunk!r}.")


def depth_groups(system: ConventionalLFMSystem, depths: tuple[float, ...]) -> dict[int, list[int]]:
    """Depth indices grouped by lenslet reach (``system.support``), nearest focus first."""
    groups: dict[int, list[int]] = defaultdict(list)
    for index, z in enumerate(depths):
        groups[system.support(z)].append(index)
    return dict(sorted(groups.items()))


def conventional_psf_stack(
    system: ConventionalLFMSystem,
    depths: tuple[float, ...],
    *,
    dtype: torch.dtype | None = None,
    accuracy: ConventionalAccuracy | None = None,
    device: torch.device | str = "cpu",
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
    design: Design | None = None,
    lenslet_focal_length: Scalar | None = None,
    mla_to_camera: Scalar | None = None,
    wavelength: Scalar | None = None,
    lenslet_aperture: Scalar | None = None,
    workers: int | None = None,
) -> PSFStack:
    """All patterns of ``system`` as one :class:`PSFStack` with data ``(S, S, Z, H, H)``.

    ``(S, S)`` is the voxel sub-position (row, column) in image orientation, ``H`` the
    widest pattern (narrower ones are zero-padded, centred); ``stack.patterns``
    (:class:`ConventionalPatterns`) lists each depth's reach so :func:`lattice_projector`
    crops them back. ``accuracy``:
    the knobs (default :class:`ConventionalAccuracy`); ``dtype``, when given, overrides its dtype.

    ``lenslet_focal_length``, ``mla_to_camera``, ``wavelength``, ``lenslet_aperture``: optional
    0-d tensors (metres) for gradients, passed to :func:`conventional_patterns` (and the
    wavelength to the Debye NIP fields); a tensor NA travels in ``system.objective``. The plan
    (reach, grids, sample counts) comes from the system's floats: pass a system holding the
    same values.

    The build is two lists of independent items: the Debye NIP fields of each depth chunk
    (``accuracy.depth_chunk`` depths of one reach), then the patterns of each depth (widest reach
    first). ``workers`` (default ``torch.get_num_threads()``, the thread policy's count) Python
    threads take the next item when free, each on 1 torch intra-op thread
    (:func:`~lfm_studio.engine.threads.run_in_workers`), on the CPU when no gradient is recorded
    (:func:`~lfm_studio.engine.threads.worker_count`); otherwise the items run in turn on the caller's threads. The
    patterns do not depend on ``workers``. ``progress`` and ``cancel`` are called on the caller's
    thread after each item; a cancel drops the items not started and raises
    :class:`~lfm_studio.engine.progress.CancelledError` once the running ones end.
    """
    acc = accuracy or ConventionalAccuracy()
    dtype = dtype or acc.dtype
    depths = tuple(float(z) for z in depths)
    if not depths:
        raise ValueError("depths is empty. Fix: give at least one depth in metres.")
    overrides = (lenslet_focal_length, mla_to_camera, wavelength, lenslet_aperture)
    workers = worker_count(workers, device, _records_graph(system, overrides))
    chunks = depth_chunks(system, depths, acc.depth_chunk)
    s, q = system.voxels_per_lenslet, system.pixels_per_lenslet
    width = (2 * max(reach for reach, _ in chunks) + 3) * q
    data = torch.zeros((s, s, len(depths), width, width), dtype=dtype, device=device)
    report = _Progress(cancel, progress, len(chunks) + len(depths))
    report("Debye NIP fields", finished=0)

    def nip_part(chunk: tuple[int, tuple[int, ...]]) -> torch.Tensor:
        # One quadrant per depth, on the grid its reach needs (near focus a fifth of the widest
        # group's area); kept for the pattern items (0.03 GB for 31 depths in the benchmark).
        reach, indices = chunk
        return nip_quadrants(
            system, tuple(depths[i] for i in indices), reach=reach, dtype=dtype, device=device,
            radial_sampling=acc.radial_sampling, model=acc.model, n_quadrature=acc.debye_points,
            oversampling=acc.nip_oversampling, wavelength=wavelength,
        )  # fmt: skip

    quadrants = run_in_workers(
        nip_part, chunks, workers, on_result=lambda k, _: report(f"Debye NIP fields (reach {chunks[k][0]})"),
    )  # fmt: skip
    # (chunk, position in it) of every depth, widest reach first: the longest items start first.
    items = sorted(
        ((k, position) for k, (_, indices) in enumerate(chunks) for position in range(len(indices))),
        key=lambda item: -chunks[item[0]][0],
    )

    def patterns(item: tuple[int, int]) -> int:
        k, position = item
        reach, i = chunks[k][0], chunks[k][1][position]
        h = (2 * reach + 3) * q
        start = (width - h) // 2
        field_n = nip_field_size(system, reach, acc.nip_oversampling)
        conventional_patterns(
            system, (depths[i],), reach=reach, dtype=dtype, device=device,
            nip_field=mirrored(quadrants[k][position : position + 1], field_n),
            nip_oversampling=acc.nip_oversampling, pixel_oversampling=acc.pixel_oversampling,
            pixel_integration=acc.pixel_integration,
            lenslet_focal_length=lenslet_focal_length, mla_to_camera=mla_to_camera, wavelength=wavelength,
            lenslet_aperture=lenslet_aperture, out=data[:, :, i : i + 1, start : start + h, start : start + h],
        )  # fmt: skip
        return i

    run_in_workers(
        patterns, items, workers, on_result=lambda _, i: report(f"patterns at z = {depths[i] * 1e6:+.1f} um"),
    )  # fmt: skip
    reach_of = [0] * len(depths)
    for reach, indices in chunks:
        for i in indices:
            reach_of[i] = reach
    report("patterns done", finished=0)
    return PSFStack(
        data,
        depths,
        system.pixel_size,
        system.magnification,
        system.wavelength,
        design=design,
        patterns=ConventionalPatterns(
            pixels_per_lenslet=q, voxels_per_lenslet=s, reach=tuple(reach_of), lenslets=system.lenslets
        ),
    )


def depth_chunks(
    system: ConventionalLFMSystem, depths: tuple[float, ...], size: int
) -> list[tuple[int, tuple[int, ...]]]:
    """``(reach, depth indices)`` of at most ``size`` depths each, a reach group's depths by ``|z|`` so that
    the depths ``+-z`` share a chunk (:func:`nip_quadrants` integrates one of them)."""
    chunks = []
    for reach, indices in depth_groups(system, depths).items():
        ordered = sorted(indices, key=lambda i: (abs(depths[i]), depths[i]))
        chunks += [(reach, tuple(ordered[start : start + size])) for start in range(0, len(ordered), size)]
    return chunks


def _records_graph(system: ConventionalLFMSystem, overrides: tuple[Scalar | None, ...]) -> bool:
    """Whether the build records an autograd graph: grad mode on and a tensor that requires grad among
    the overrides, the objective's fields (a tensor NA) or the pupil phase's waves."""
    objective = system.objective
    values = [
        *overrides,
        *(getattr(objective, field.name) for field in dataclass_fields(objective)),
        *(waves for _, waves in system.pupil_zernike_waves),
    ]
    return torch.is_grad_enabled() and any(isinstance(v, torch.Tensor) and v.requires_grad for v in values)


class _Progress:
    """Progress of ``total`` items, reported on the caller's thread: each call adds ``finished``
    items and calls :func:`checkpoint` (which raises when ``cancel`` is set)."""

    def __init__(self, cancel: CancelToken, progress: ProgressCallback | None, total: int) -> None:
        self.cancel, self.progress, self.total, self.done = cancel, progress, total, 0

    def __call__(self, message: str, finished: int = 1) -> None:
        self.done += finished
        checkpoint(self.cancel, self.progress, self.done, self.total, message)


def lattice_projector(stack: PSFStack, lenslets: tuple[int, int] | None = None) -> LensletLatticeProjector:
    """The conventional projector of a pattern stack from :func:`conventional_psf_stack`, on the
    stack's device and dtype; ``lenslets`` ``(Ly, Lx)`` overrides the stack's lenslet count."""
    layout = stack.patterns
    if layout is None:
        raise ValueError(
            "stack is not a conventional-LFM pattern stack (its patterns are None: per-depth "
            f"shift-invariant PSFs of shape {tuple(stack.data.shape)}). Fix: build it with "
            "conventional_psf_stack / simulate_psf of a conventional design, or use a ShiftInvariantProjector."
        )
    q = layout.pixels_per_lenslet
    grid = layout.lenslets if lenslets is None else (int(lenslets[0]), int(lenslets[1]))
    width = stack.data.shape[-1]
    grouped: dict[int, list[int]] = defaultdict(list)
    for index, reach in enumerate(layout.reach):
        grouped[reach].append(index)
    built = []
    for reach, indices in sorted(grouped.items()):
        h = (2 * reach + 3) * q
        start = (width - h) // 2
        patterns = stack.data[:, :, indices, start : start + h, start : start + h].permute(2, 0, 1, 3, 4)
        built.append((indices, patterns))
    return LensletLatticeProjector(built, len(stack.depths), grid, q)


def conventional_projector(
    system: ConventionalLFMSystem,
    depths: tuple[float, ...],
    *,
    dtype: torch.dtype | None = None,
    accuracy: ConventionalAccuracy | None = None,
    device: torch.device | str = "cpu",
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
    workers: int | None = None,
) -> tuple[LensletLatticeProjector, PSFStack]:
    """Build ``A`` / ``A^T`` of ``system`` for ``depths`` (metres); also returns the pattern stack
    (``workers``: :func:`conventional_psf_stack`'s)."""
    stack = conventional_psf_stack(
        system, depths, dtype=dtype, accuracy=accuracy, device=device, progress=progress, cancel=cancel,
        workers=workers,
    )  # fmt: skip
    return lattice_projector(stack, system.lenslets), stack
