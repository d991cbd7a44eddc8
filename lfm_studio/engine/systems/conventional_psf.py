"""Conventional-LFM operator build: patterns per depth group, one pattern stack, the lattice projector."""

from __future__ import annotations

from collections import defaultdict

import torch

from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.systems.conventional_patterns import conventional_patterns, nip_fields
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem


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
    dtype: torch.dtype = torch.float32,
    device: torch.device | str = "cpu",
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
    design: object | None = None,
) -> PSFStack:
    """All patterns of ``system`` as one :class:`PSFStack` with data ``(S, S, Z, H, H)``.

    ``(S, S)`` is the voxel sub-position (row, column) in image orientation, ``H`` the
    widest pattern (narrower ones are zero-padded, centred); ``metadata["reach"]`` lists
    each depth's reach so :func:`lattice_projector` crops them back.
    """
    depths = tuple(float(z) for z in depths)
    if not depths:
        raise ValueError("depths is empty. Fix: give at least one depth in metres.")
    groups = depth_groups(system, depths)
    # One Debye evaluation for every depth, on the widest grid any group needs.
    fields = nip_fields(system, depths, reach=max(groups), dtype=dtype, device=device)
    s, q = system.voxels_per_lenslet, system.pixels_per_lenslet
    width = (2 * max(groups) + 3) * q
    data = torch.zeros((s, s, len(depths), width, width), dtype=dtype, device=device)
    reach_of = [0] * len(depths)
    for done, (reach, indices) in enumerate(groups.items()):
        checkpoint(
            cancel, progress, done, len(groups), f"depth group {done + 1}/{len(groups)} (reach {reach})"
        )
        patterns = conventional_patterns(
            system, tuple(depths[i] for i in indices), reach=reach, dtype=dtype, device=device,
            cancel=cancel, nip_field=fields[indices],
        )  # fmt: skip
        h = patterns.shape[-1]
        start = (width - h) // 2
        data[:, :, indices, start : start + h, start : start + h] = patterns.permute(1, 2, 0, 3, 4)
        for i in indices:
            reach_of[i] = reach
    checkpoint(cancel, progress, len(groups), len(groups), "patterns done")
    return PSFStack(
        data,
        depths,
        system.pixel_size,
        system.magnification,
        system.wavelength,
        design=design,
        metadata={
            "kind": "conventional",
            "pixels_per_lenslet": q,
            "voxels_per_lenslet": s,
            "reach": reach_of,
            "lenslets": list(system.lenslets),
        },
    )


def lattice_projector(stack: PSFStack, lenslets: tuple[int, int] | None = None) -> LensletLatticeProjector:
    """The conventional projector of a pattern stack from :func:`conventional_psf_stack`."""
    meta = stack.metadata
    if meta.get("kind") != "conventional" or stack.data.ndim != 5:
        raise ValueError(
            "stack is not a conventional-LFM pattern stack (expected data (S, S, Z, H, H) and "
            f"metadata kind 'conventional'); got shape {tuple(stack.data.shape)}, kind {meta.get('kind')!r}."
        )
    q = int(meta["pixels_per_lenslet"])
    lenslets = tuple(lenslets or meta["lenslets"])
    width = stack.data.shape[-1]
    grouped: dict[int, list[int]] = defaultdict(list)
    for index, reach in enumerate(meta["reach"]):
        grouped[int(reach)].append(index)
    built = []
    for reach, indices in sorted(grouped.items()):
        h = (2 * reach + 3) * q
        start = (width - h) // 2
        patterns = stack.data[:, :, indices, start : start + h, start : start + h].permute(2, 0, 1, 3, 4)
        built.append((indices, patterns))
    return LensletLatticeProjector(built, len(stack.depths), lenslets, q)


def conventional_projector(
    system: ConventionalLFMSystem,
    depths: tuple[float, ...],
    *,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str = "cpu",
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> tuple[LensletLatticeProjector, PSFStack]:
    """Build ``A`` / ``A^T`` of ``system`` for ``depths`` (metres); also returns the pattern stack."""
    stack = conventional_psf_stack(
        system, depths, dtype=dtype, device=device, progress=progress, cancel=cancel
    )
    return lattice_projector(stack, system.lenslets), stack
