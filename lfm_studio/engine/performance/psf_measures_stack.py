"""A small PSF stack to measure a design's metrics on (``lfm-studio info --measure``).

Two depth sets, each computed with the per-lenslet Fourier-LFM model
(:func:`~lfm_studio.engine.systems.fourier_psf.fourier_psf_stack`) and merged:

- **fine**: ``fine`` depths around the focus of the largest lenslet group, spaced by a
  third of the closed-form axial resolution, for the axial correlation width and the
  axial two-point test (both need several slices within one resolution step);
- **coarse**: ``coarse`` depths evenly over the closed-form depth range widened by a
  quarter on each side, for the depth of field (those within the fine span dropped).

Accuracy (speed first, enough for metrics): 2 x 2 sub-samples per pixel (exact pixel
integration of the sub-sampled field), a diffraction margin of 8 ``lambda d / D`` per
lenslet window (about 2.5 % of a spot's power falls outside and is dropped), the
design's objective model and dtype, lenslets computed apart even when their light
footprints touch (their intensities add; interference between neighbouring
sub-images is ignored). The sensor is cropped to the region the lenslets light.
Measured: 1-16 s for the bundled Fourier presets on a shared 2-core CPU.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import replace

import torch

from lfm_studio.engine.design import Design
from lfm_studio.engine.performance.closed_forms import ClosedFormMetrics, closed_form_metrics
from lfm_studio.engine.performance.fourier_closed_forms import focus_depth, views
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.systems.fourier_psf import fourier_psf_stack
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem
from lfm_studio.engine.systems.fourier_windows import footprint_radius
from lfm_studio.engine.systems.from_design import fourier_accuracy_of, fourier_system_of
from lfm_studio.engine.systems.kinds import kind_of

MARGIN_AIRY = 8.0
"""Diffraction margin of the lenslet windows, in ``lambda d / D`` (see the module docstring)."""


def main_focus_depth(design: Design) -> float:
    """Focus depth (m) of the lenslet focal length shared by most views (the shortest on a tie)."""
    counts = Counter(lens.focal_length for lens in views(design)) or Counter(
        lens.focal_length for lens in design.mla.lenslets
    )
    focal = min(counts, key=lambda f: (-counts[f], f))
    return focus_depth(design, focal)


def measurement_depths(
    design: Design, closed: ClosedFormMetrics | None = None, *, fine: int = 11, coarse: int = 7
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The fine and the coarse depth sets (metres) of the module docstring."""
    closed = closed or closed_form_metrics(design)
    centre = main_focus_depth(design)
    resolution = closed.axial_resolution or closed.depth_of_field / 10.0
    step = resolution / 3.0
    fine_depths = tuple(centre + step * (k - fine // 2) for k in range(fine))
    lo, hi = closed.depth_range
    pad = 0.25 * (hi - lo)
    grid = (lo - pad + (hi - lo + 2.0 * pad) * k / (coarse - 1) for k in range(coarse))
    # Coarse depths inside the fine set's span add nothing and, a hair away from a fine
    # depth, would make the depth curves' interpolation ill-conditioned: leave them out.
    span = (fine_depths[0] - step / 2.0, fine_depths[-1] + step / 2.0)
    coarse_depths = tuple(z for z in grid if not span[0] <= z <= span[1])
    return fine_depths, coarse_depths


def cropped_system(system: FourierLFMSystem, depths: tuple[float, ...]) -> FourierLFMSystem:
    """``system`` with the sensor cut (about the axis) to the pixels its lenslets can light."""
    reach = max(
        max(abs(lens.center[0]), abs(lens.center[1])) + footprint_radius(system, lens, depths, MARGIN_AIRY)
        for lens in system.mla.lenslets
    )
    half = math.ceil(reach / system.pixel_pitch) + 2
    ny, nx = system.sensor_shape
    shape = (min(ny, 2 * half + ny % 2), min(nx, 2 * half + nx % 2))
    return replace(system, sensor_shape=shape)


def unmeasurable_reason(subject: object) -> str | None:
    """Why the PSF measures cannot run on ``subject``'s kind (a design or its metrics), or None.

    The measures (FWHM, two-point resolution, depth of field) need one laterally shift-invariant
    PSF per depth. A kind whose PSF changes with the source position behind each lenslet (the
    conventional LFM) has none; ``lfm-studio resolution`` measures its resolution by
    reconstructing two points instead.
    """
    kind = kind_of(subject)
    if kind.shift_invariant:
        return None
    return (
        f"a {kind.title} cannot be measured on its PSF: the measures need one laterally shift-invariant "
        "PSF per depth, and its PSF changes with the source position behind each lenslet"
    )


def measurement_psf(
    design: Design,
    *,
    fine: int = 11,
    coarse: int = 7,
    device: torch.device | str = "cpu",
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> PSFStack:
    """PSF stack of a Fourier-LFM ``design`` on the depths of :func:`measurement_depths`.

    Raises NotImplementedError for a design whose stack cannot be measured (:func:`unmeasurable_reason`).
    """
    why = unmeasurable_reason(design)
    if why is not None:
        raise NotImplementedError(f"{why}; only the closed-form metrics are available for this design.")
    accuracy = replace(
        fourier_accuracy_of(design), oversampling=2, margin_airy=MARGIN_AIRY, method="per_lenslet"
    )
    stacks = []
    for depths in measurement_depths(design, fine=fine, coarse=coarse):
        if not depths:
            continue
        system = cropped_system(fourier_system_of(design), depths)
        stacks.append(
            fourier_psf_stack(
                system,
                depths,
                accuracy=accuracy,
                device=device,
                progress=progress,
                cancel=cancel,
                design=design,
            )
        )
    # Both stacks share the sensor crop only if it came out the same: place each on the larger one.
    ny = max(s.data.shape[-2] for s in stacks)
    nx = max(s.data.shape[-1] for s in stacks)
    slices: list[torch.Tensor] = []
    all_depths: list[float] = []
    for stack in stacks:
        pad_y, pad_x = (ny - stack.data.shape[-2]) // 2, (nx - stack.data.shape[-1]) // 2
        slices.append(torch.nn.functional.pad(stack.data, (pad_x, pad_x, pad_y, pad_y)))
        all_depths.extend(stack.depths)
    data = torch.cat(slices)
    order = sorted(range(len(all_depths)), key=all_depths.__getitem__)
    return replace(
        stacks[0],
        data=data[order],
        depths=tuple(all_depths[i] for i in order),
        metadata={**stacks[0].metadata, "purpose": "design metrics (fine + coarse depths)"},
    )
