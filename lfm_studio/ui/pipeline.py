"""The studio's background stages as plain functions ``(ctx, ...) -> result`` (Qt-free).

Each runs on a worker thread (:mod:`lfm_studio.widgets.jobs`): it reports through
``ctx.progress``, stops when ``ctx.cancel`` is set (the engine's cancel token) and
returns detached CPU tensors in the records of :mod:`lfm_studio.ui.results`.

Stages: design -> PSF stack (a quick preview first for big designs) -> design metrics
measured on it; PSF -> light-field image of a phantom -> reconstruction (a method of the engine's
registry, accelerated Richardson-Lucy by default) scored against the phantom (NCC, bead F1, PSNR/SSIM beside the all-zero volume's).
"""

from __future__ import annotations

import importlib.util
import time
from dataclasses import dataclass
from typing import Any, Protocol

import torch

from lfm_studio.engine.design import AccuracySpec, Design
from lfm_studio.engine.performance import DesignMetrics, compute_design_metrics
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.simulation import simulate_psf
from lfm_studio.engine.systems.fourier_psf import FourierPSFReport
from lfm_studio.engine.systems.kinds import kind_of
from lfm_studio.engine.systems.lenslet_cache import LensletCache
from lfm_studio.ui.edits import try_changes
from lfm_studio.ui.results import ImageResult, PSFProfiles, PSFResult, ReconstructionResult, WorkflowSettings
from lfm_studio.widgets.viewer.display_data import image_display, psf_display, rectified_note, volume_display

PREVIEW_DEPTHS = 5  # depths of the quick preview (spread over the design's range)
PREVIEW_BINNING_FROM = 1024  # sensors with at least this many pixels per side are binned 2x for the preview
LATERAL_HALF_WIDTH = 20  # pixels either side of the peak in the lateral profile


class Context(Protocol):
    """What a stage needs from :class:`lfm_studio.widgets.jobs.JobContext`."""

    cancel: Any

    def progress(self, done: int, total: int, message: str = "") -> None: ...

    def partial(self, value: Any) -> None: ...

    def check(self, message: str = "cancelled") -> None: ...


# ----- PSF -----


def preview_design(design: Design) -> Design | None:
    """A cheaper variant of ``design`` for the quick preview, or None when the design is small already.

    The "preview" accuracy preset (1 sub-sample per pixel with the exact pixel integration, Debye
    objective: <= 5 % PSF error, :data:`PRESET_ERROR_BOUNDS`) and, for big sensors of a kind whose
    PSF keeps its geometry when binned (``kind.binnable_sensor``: Fourier), 2 x 2 pixel binning
    (same sensor area, same sub-image positions).
    """
    ny, nx = design.camera.pixel_count
    big_sensor = min(ny, nx) >= PREVIEW_BINNING_FROM
    if design.depths.count <= PREVIEW_DEPTHS and not big_sensor:
        return None
    changes: dict[str, Any] = {"accuracy": AccuracySpec.from_preset("preview")}
    if big_sensor and kind_of(design).binnable_sensor:
        binned = {
            "camera.pixel_pitch_um": 2.0 * design.camera.pixel_pitch_um,
            "camera.pixel_count": (ny // 2, nx // 2),
        }
        outcome = try_changes(design, {**changes, **binned})
        if outcome.ok:
            return outcome.design
    outcome = try_changes(design, changes)
    return outcome.design if outcome.ok else design


def preview_depths(design: Design, count: int = PREVIEW_DEPTHS) -> tuple[float, ...]:
    """``count`` of the design's depths (metres), evenly spread and including both ends."""
    values = design.depths.values
    if len(values) <= count:
        return tuple(values)
    picks = sorted({round(i * (len(values) - 1) / (count - 1)) for i in range(count)})
    return tuple(values[i] for i in picks)


@dataclass(frozen=True)
class PSFRequest:
    """What the PSF stage computes: the design, on which device, and the preview to show first."""

    design: Design
    device: str = "cpu"
    preview: Design | None = None
    preview_depths: tuple[float, ...] = ()

    @classmethod
    def for_design(cls, design: Design, *, device: str = "cpu", preview: bool = True) -> PSFRequest:
        reduced = preview_design(design) if preview else None
        depths = preview_depths(design) if reduced is not None else ()
        return cls(design, device, reduced, depths)


def _stack(
    design: Design,
    depths: tuple[float, ...],
    device: str,
    cache: LensletCache | None,
    ctx: Context,
    label: str,
) -> tuple[PSFStack, str, tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]]:
    def progress(done: int, total: int, message: str) -> None:
        ctx.progress(done, total, f"{label}: {message}")

    report = FourierPSFReport()
    stack = simulate_psf(
        design, depths=depths, device=device, progress=progress, cancel=ctx.cancel, cache=cache, report=report
    )
    lenslets = (
        tuple(report.lenslets_computed),
        tuple(report.lenslets_cached),
        tuple(report.lenslets_off_sensor),
    )
    return stack, report.method, lenslets


def _psf_result(
    design: Design, run: Design, depths: tuple[float, ...], device: str, cache, ctx: Context, preview: bool
) -> PSFResult:
    start = time.perf_counter()
    label = f"PSF preview ({len(depths)} depths)" if preview else f"PSF stack ({len(depths)} depths)"
    stack, method, (computed, cached, off_sensor) = _stack(run, depths, device, cache, ctx, label)
    stack = stack.with_data(stack.data.detach().cpu())
    ctx.check()
    return PSFResult(
        design, stack, preview, method, computed, cached, off_sensor, psf_profiles(stack),
        time.perf_counter() - start, display=psf_display(stack, "PSF"),
    )  # fmt: skip


def compute_psf(ctx: Context, request: PSFRequest, cache: LensletCache | None) -> PSFResult:
    """The PSF stage: the preview (handed over with ``ctx.partial``) when asked, then the full stack.

    A preview the engine refuses (its reduced design is not computable, e.g. pixels binned too
    coarse for the lenslet apertures) is skipped with a progress message: it must not cost the
    full stack.
    """
    if request.preview is not None:
        try:
            preview = _psf_result(
                request.design, request.preview, request.preview_depths, request.device, cache, ctx, True
            )
        except ValueError as error:  # the reduced design is not computable (e.g. binned too coarse)
            ctx.progress(0, 1, f"PSF preview skipped ({error}); computing the full stack")
        else:
            ctx.partial(preview)
    depths = tuple(request.design.depths.values)
    return _psf_result(request.design, request.design, depths, request.device, cache, ctx, False)


def _fourier_slices(stack: PSFStack) -> torch.Tensor:
    """The ``(Z, Y, X)`` PSFs of a stack (a conventional stack's central lenslet pattern)."""
    data = stack.data.detach()
    if not stack.shift_invariant:  # conventional patterns (S, S, Z, H, H): the on-axis source position
        s = data.shape[0]
        return data[s // 2, s // 2]
    return data.reshape(-1, *data.shape[-3:])[0]


def psf_profiles(stack: PSFStack) -> PSFProfiles:
    """Lateral profile through the brightest pixel of the sharpest slice, and peak versus depth."""
    data = _fourier_slices(stack).float()
    peaks = data.amax(dim=(-2, -1))
    k = int(peaks.argmax())
    image = data[k]
    y0, x0 = divmod(int(image.argmax()), image.shape[-1])
    lo, hi = max(0, x0 - LATERAL_HALF_WIDTH), min(image.shape[-1], x0 + LATERAL_HALF_WIDTH + 1)
    row = image[y0, lo:hi]
    scale = float(row.max()) or 1.0
    pixel = stack.pixel_size / stack.magnification
    lateral_x = (torch.arange(lo, hi, dtype=torch.float64) - x0) * pixel
    top = float(peaks.max()) or 1.0
    return PSFProfiles(
        lateral_x, (row / scale).double(), stack.depth_tensor(), (peaks / top).double(), stack.depths[k]
    )


def measure_design(ctx: Context, design: Design, stack: PSFStack | None) -> DesignMetrics:
    """Design metrics with the requirement checks, measured on ``stack`` when it is a ``(Z, Y, X)`` stack."""
    ctx.progress(0, 1, "measuring design metrics")
    usable = stack is not None and stack.shift_invariant and stack.data.ndim == 3 and len(stack.depths) >= 3
    metrics = compute_design_metrics(design, psf=stack if usable else None)
    ctx.progress(1, 1, "design metrics")
    return metrics


# ----- image and reconstruction -----


def simulate_image(
    ctx: Context, design: Design, stack: PSFStack, settings: WorkflowSettings, device: str = "cpu"
) -> ImageResult:
    """Phantom (beads, cells or a TIFF volume) -> noisy light-field image through ``stack``."""
    from lfm_studio.engine.phantoms import DEFAULT_BEADS
    from lfm_studio.engine.simulation import camera_of, imaging_setup, light_field_image, make_phantom

    ctx.progress(0, 3, "image: building the projector")
    setup = imaging_setup(stack.to(device))
    ctx.check()
    ctx.progress(1, 3, "image: phantom")
    if settings.phantom == "tiff":
        if not settings.tiff_path:
            raise ValueError(
                "phantom 'TIFF volume' needs a file. Fix: choose a volume TIFF in the workflow panel."
            )
        from lfm_studio.engine.phantoms import from_tiff

        volume = from_tiff(settings.tiff_path, normalize=True, device=device).data
        info: dict[str, Any] = {"phantom": str(settings.tiff_path)}
        if tuple(volume.shape) != tuple(setup.volume_shape):
            voxel_um = tuple(round(v * 1e6, 4) for v in setup.voxel_size)
            raise ValueError(
                f"{settings.tiff_path} has shape {tuple(volume.shape)} but this PSF stack images volumes of "
                f"shape {tuple(setup.volume_shape)} (Z, Y, X) with voxels {voxel_um} um. Fix: resample the volume."
            )
    else:
        count = (
            settings.bead_count or None
        )  # 0: as many as fit (the engine's default, as in `lfm-studio image`)
        volume, info = make_phantom(settings.phantom, setup, seed=settings.seed, count=count)
        if "note" in info:  # fewer than the default fit; the engine's note names the CLI's --count
            info["note"] = (
                f"{info['objects']} beads: as many as fit in this volume (at most {DEFAULT_BEADS}). "
                "Type a number in Beads for another count (at most what fits)."
            )
        volume = volume.to(device)
    ctx.check()
    ctx.progress(2, 3, "image: light field")
    counts, expected = light_field_image(
        setup, volume, camera_of(design), photons=settings.photons, seed=settings.seed
    )
    ctx.progress(3, 3, "image: done")
    info = {**info, "photons": settings.photons}
    counts = counts.detach().cpu()
    return ImageResult(
        counts, expected.detach().cpu(), volume.detach().cpu(), tuple(setup.voxel_size),
        stack.pixel_size, setup, info, display=image_display(counts, stack.pixel_size, "light field", note=rectified_note(stack)),
        truth_display=volume_display(volume.detach().cpu(), tuple(setup.voxel_size), "phantom"),
    )  # fmt: skip


def reconstruction_available() -> bool:
    """Whether the engine has its reconstruction methods (``lfm_studio.engine.reconstruct``) and the metrics."""
    return all(
        importlib.util.find_spec(name) is not None
        for name in ("lfm_studio.engine.reconstruct", "lfm_studio.engine.image_quality")
    )


def photon_counts(image: ImageResult, design: Design) -> tuple[torch.Tensor, float]:
    """Camera counts (ADU) back to photons and the noise floor they carry (the background to model):
    the engine's :func:`~lfm_studio.engine.io.counts_to_photons`, as in ``lfm-studio reconstruct``."""
    from lfm_studio.engine.io.camera_counts import counts_to_photons, design_camera

    if image.info.get("photons") is None:  # noise-free, or a calibrated raw frame: already photons
        return image.counts.clamp_min(0.0), float(image.info.get("noise_floor_photons", 0.0))
    return counts_to_photons(image.counts, design_camera(design.camera), name="the simulated image")


def reconstruction_refusal(settings: WorkflowSettings) -> str | None:
    """Why the studio cannot start ``settings``' reconstruction, in the studio's words, or None.

    The Learned model method needs a checkpoint file in its Model field (the engine's own message
    names the CLI's ``--model`` and ``lfm-studio train``); checked before the job starts.
    """
    if settings.method != "learned":
        return None
    from pathlib import Path

    path = dict(settings.method_options).get("model")
    fix = (
        "Fix: train a model in the Train dock and press Save checkpoint…, then choose that file "
        "in the Model field (…), or choose a checkpoint written by `lfm-studio train`."
    )
    if not path:
        return f"the Learned model method needs a checkpoint file in its Model field, which is empty. {fix}"
    if not Path(path).expanduser().is_file():
        return f"Model field: no checkpoint file {path}. {fix}"
    return None


def peak_mode(settings: WorkflowSettings) -> bool | None:
    """Whether to score bead F1: on for beads, off for cells, judged from the volume for a TIFF."""
    return {"beads": True, "cells": False}.get(settings.phantom)


def reconstruction_options(method: Any, settings: WorkflowSettings, floor: float) -> dict[str, Any]:
    """The options of ``method`` (a registry :class:`~lfm_studio.engine.reconstruct.Method`) from the
    workflow settings: the camera's noise floor as background, the iterations when it takes them,
    the panel's other options."""
    given = {**dict(settings.method_options), "background": floor}
    if method.option("iterations") is not None:
        given["iterations"] = settings.iterations
    return method.resolve({k: v for k, v in given.items() if method.option(k) is not None})


def reconstruct(
    ctx: Context, design: Design, image: ImageResult, settings: WorkflowSettings
) -> ReconstructionResult:
    """The image reconstructed with the registry's ``settings.method``, scored against the phantom.

    A method with iterates (Richardson-Lucy) hands over, after each iteration, the NCC with the
    truth (``ctx.partial`` of ``(ncc per iteration, relative change per iteration)``); a one-step
    method (Wiener, Tikhonov, ...) reports its progress only. At the end: the scorecard (NCC, bead
    F1, PSNR, SSIM, each beside the all-zero volume's score).
    """
    from lfm_studio.engine.image_quality import ncc, scorecard
    from lfm_studio.engine.reconstruct import check_reconstruction, get_method

    method = get_method(settings.method)
    projector = image.setup.projector
    method.check_projector(projector)
    counts, floor = photon_counts(image, design)
    counts = counts.to(projector.device)
    options = reconstruction_options(method, settings, floor)
    truth = image.ground_truth
    total = method.steps(options)
    nccs: list[float] = []
    changes: list[float] = []
    estimate = None
    counts = counts.to(projector.device)
    if method.iterates is not None:
        for it in method.iterates(projector, counts, options, _rl_progress(ctx), ctx.cancel):
            estimate = it.estimate.detach().cpu()
            changes.append(float(it.relative_change))
            if truth is not None:  # a measured raw frame has no ground truth
                nccs.append(float(ncc(truth, estimate)))
            ctx.partial((tuple(nccs), tuple(changes)))
    else:
        estimate = method(projector, counts, options, _rl_progress(ctx), ctx.cancel).detach().cpu()
        if truth is not None:
            nccs.append(float(ncc(truth, estimate)))
    if estimate is None:
        raise ValueError("reconstruction ran no iteration. Fix: set iterations >= 1.")
    check_reconstruction(estimate)  # all zero, constant or NaN/Inf: an error, not a result
    if truth is None:
        display = volume_display(estimate, image.voxel_size, "reconstruction")
        summary = "measured frame: no ground truth to score against"
        return ReconstructionResult(
            estimate, image.voxel_size, len(changes), tuple(changes), display=display, summary=summary,
            method=method.name,
        )  # fmt: skip
    ctx.progress(total, total, "reconstruction: scoring against the phantom")
    card = scorecard(
        truth, estimate, normalize="scale", peaks=peak_mode(settings), voxel_size=image.voxel_size,
        floors=("zero",),
    )  # fmt: skip
    noun = "beads" if settings.phantom == "beads" else "objects"
    return ReconstructionResult(
        estimate,
        image.voxel_size,
        len(changes),
        tuple(changes),
        float(card.report.psnr),
        float(card.report.ssim),
        display=volume_display(estimate, image.voxel_size, "reconstruction"),
        ncc_curve=tuple(nccs),
        scores=card,
        summary=card.summary(noun=noun),
        method=method.name,
    )


def _rl_progress(ctx: Context):
    def progress(done: int, total: int, message: str) -> None:
        ctx.progress(done, total, f"reconstruction: {message}")

    return progress
