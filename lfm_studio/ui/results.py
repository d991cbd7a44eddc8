"""What the studio's background stages produce (plain frozen records, Qt-free).

Tensors inside are detached and on the CPU (they cross from worker threads to the
GUI thread). Lengths are SI metres, as in the engine.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import torch

from lfm_studio.engine.design import Design
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.widgets.job_status import JobStatus as JobStatus  # re-exported: lives with the job runner

STAGES = ("psf", "image", "reconstruction")
"""The recompute chain: a stage is stale when anything it depends on changed."""


@dataclass(frozen=True)
class PSFProfiles:
    """Lateral and axial PSF profiles for the plots (sample side, normalised to a peak of 1).

    Attributes
    ----------
    lateral_x : (N,) positions in metres relative to the peak, along x at the sharpest slice.
    lateral : (N,) intensity along that line.
    axial_z : (Z,) depths in metres.
    axial : (Z,) peak intensity of each depth slice.
    focus_depth : depth of the sharpest slice, metres.
    """

    lateral_x: torch.Tensor
    lateral: torch.Tensor
    axial_z: torch.Tensor
    axial: torch.Tensor
    focus_depth: float


@dataclass(frozen=True)
class PSFResult:
    """One computed PSF stack with what produced it.

    Attributes
    ----------
    design : the design in force when the job started (the full one, also for a preview).
    stack : the stack (for a preview: of the reduced preview design).
    preview : True for the quick preview (few depths, reduced sensor and accuracy).
    method : "per_lenslet", "per_lenslet_coherent", "full_field" or "conventional".
    lenslets_computed, lenslets_cached : per-lenslet cache use (Fourier per-lenslet path).
    lenslets_off_sensor : lenslets skipped because their light misses the sensor (computed
        neither fresh nor from the cache).
    profiles : for the plots.
    seconds : wall time of the computation.
    display : the stack prepared for the viewer on the worker thread (``psf_display``), or None.
    """

    design: Design
    stack: PSFStack
    preview: bool
    method: str
    lenslets_computed: tuple[int, ...] = ()
    lenslets_cached: tuple[int, ...] = ()
    lenslets_off_sensor: tuple[int, ...] = ()
    profiles: PSFProfiles | None = None
    seconds: float = 0.0
    display: Any = None


@dataclass(frozen=True)
class ImageResult:
    """A simulated light-field image with its ground truth and the projector that made it.

    Attributes
    ----------
    counts : (Py, Px) camera counts in ADU (the noise-free image when ``photons`` is None).
    expected : (Py, Px) noise-free image.
    ground_truth : (Z, Y, X) phantom volume, or None for a measured raw frame (nothing to score against).
    voxel_size : (dz, dy, dx) metres.
    pixel_size : sensor pixel pitch, metres.
    setup : the :class:`~lfm_studio.engine.simulation.ImagingSetup` (reused by the reconstruction).
    info : phantom description (kind, seed, object count, photons).
    display : ``counts`` prepared for the viewer on the worker thread (``image_display``), or None.
    truth_display : ``ground_truth`` prepared likewise (``volume_display``, layer "phantom"), or None.
    """

    counts: torch.Tensor
    expected: torch.Tensor
    ground_truth: torch.Tensor | None
    voxel_size: tuple[float, float, float]
    pixel_size: float
    setup: Any
    info: dict[str, Any] = field(default_factory=dict)
    display: Any = None
    truth_display: Any = None


@dataclass(frozen=True)
class ReconstructionResult:
    """A reconstructed volume with its convergence curves and quality against the ground truth.

    Attributes
    ----------
    volume : (Z, Y, X) estimate.
    voxel_size : (dz, dy, dx) metres.
    iterations : iterations run.
    change_curve : relative change ``|x_k - x_{k-1}| / |x_{k-1}|`` after each iteration.
    psnr, ssim : final PSNR (dB) and SSIM after scale matching (None when they cannot be computed).
    display : ``volume`` prepared for the viewer on the worker thread (``volume_display``), or None.
    ncc_curve : NCC (Pearson correlation) with the ground truth after each iteration.
    scores : the final :class:`~lfm_studio.engine.image_quality.Scorecard` (NCC, F1 for beads, PSNR,
        SSIM with their all-zero floors), or None.
    summary : ``scores`` in one line, NCC and F1 first (what the workflow panel shows).
    method : the registry name of the method that made it ("" when unknown).
    """

    volume: torch.Tensor
    voxel_size: tuple[float, float, float]
    iterations: int
    change_curve: tuple[float, ...] = ()
    psnr: float | None = None
    ssim: float | None = None
    display: Any = None
    ncc_curve: tuple[float, ...] = ()
    scores: Any = None
    summary: str = ""
    method: str = ""

    @property
    def ncc(self) -> float | None:
        """Final NCC with the ground truth, or None."""
        return None if self.scores is None else self.scores.score("ncc").value

    @property
    def f1(self) -> float | None:
        """Final bead F1 (matched local maxima), or None when peaks were not matched."""
        score = None if self.scores is None else self.scores.score("f1")
        return None if score is None else score.value


@dataclass(frozen=True)
class WorkflowSettings:
    """What the workflow panel asks for: phantom, photon budget, seed, reconstruction.

    Attributes
    ----------
    phantom : "beads", "cells" or "tiff".
    bead_count : number of beads (phantom "beads"); 0 (the default): as many as fit, up to 50, the
        engine's default count that ``lfm-studio image`` uses too.
    tiff_path : volume TIFF (phantom "tiff").
    photons : expected photons in the image; None = noise-free.
    seed : random seed of phantom and noise.
    iterations : iterations of an iterative method (Richardson-Lucy).
    method : a reconstruction method of :mod:`lfm_studio.engine.reconstruct.registry`.
    method_options : its other options as ``(name, value)`` pairs (not iterations, not background:
        the background is the camera's noise floor).
    auto_update : recompute image and reconstruction when the design changes.
    """

    phantom: str = "beads"
    bead_count: int = 0
    tiff_path: str | None = None
    photons: float | None = 1e6
    seed: int = 0
    iterations: int = 10
    auto_update: bool = True
    method: str = "rl-accelerated"
    method_options: tuple[tuple[str, Any], ...] = ()

    IMAGE_FIELDS = ("phantom", "bead_count", "tiff_path", "photons", "seed")
    RECONSTRUCTION_FIELDS = ("iterations", "method", "method_options")

    def image_changed(self, other: WorkflowSettings) -> bool:
        """Whether the image stage depends on something that differs between the two settings."""
        return any(getattr(self, f) != getattr(other, f) for f in self.IMAGE_FIELDS)

    def reconstruction_changed(self, other: WorkflowSettings) -> bool:
        """Whether the reconstruction settings (method, its options, iterations) differ: options left
        out and the same options written out at their defaults are the same settings."""
        return (
            self.iterations != other.iterations
            or self.method != other.method
            or self.resolved_options() != other.resolved_options()
        )

    def resolved_options(self) -> dict[str, Any]:
        """The method's options as a run uses them: those given, every other at its default (as given
        when the method is unknown or the reconstruction package is missing)."""
        given = dict(self.method_options)
        try:
            from lfm_studio.engine.reconstruct import get_method

            defaults = get_method(self.method).defaults()
        except (ImportError, ValueError):
            return given
        return {**defaults, **given}
