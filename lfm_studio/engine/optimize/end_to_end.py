"""End-to-end optimisation (thesis 5.3.2): optics and a differentiable reconstruction trained jointly.

Each step of :func:`optimize_end_to_end`:

1. the PSF stack of the current optics through the differentiable fast path
   (:meth:`.gradient_params.SpaceBinding.psf_stack`), and its projector: for a Fourier LFM the
   shift-invariant projector on a volume grid fixed at the start (the lateral voxel count of the
   start design; the voxel follows the magnification), for a conventional LFM the lenslet-lattice
   projector of the pattern stack (:meth:`~lfm_studio.engine.systems.kinds_conventional.ConventionalKind.imaging_setup`;
   its grid, lenslets times voxels per lenslet, does not change: pitch and counts are not freed);
2. ``batch`` seeded training phantoms (:func:`lfm_studio.engine.learned.data.make_sample`, split
   ``train``, indices ``step * batch + i``: a new batch every step) imaged at the photon budget of
   ``data`` (Poisson shot noise and Gaussian read noise). The noise realisation is held fixed
   while differentiating: ``image = A(theta) x + (noisy - A(theta) x).detach()``, so the gradient
   reaches the optics through the expected image (the usual reparameterisation for Poisson data);
3. the reconstruction: ``"unrolled-rl"``, the learned unrolled Richardson-Lucy model
   (:class:`lfm_studio.engine.learned.models.unrolled_rl.UnrolledRL`, run with the current
   projector), or ``"rl"``, plain unrolled Richardson-Lucy
   (:func:`lfm_studio.engine.reconstruct.unrolled.richardson_lucy_unrolled`, nothing to train);
4. the task loss: the energy-normalised MSE of engine/learned
   (:func:`lfm_studio.engine.learned.losses.training_loss`; the all-zero volume scores ``1 +
   high_pass_weight``, the *floor*), averaged over the batch; Adam / L-BFGS steps on the optics
   (normalised to ``[0, 1]`` and projected on the bounds, as :mod:`.gradient`) and the
   reconstruction weights (``lr_reconstruction``), either side frozen on request.

Held-out phantoms (split ``test``, never trained on) are scored at the start and the end (and
after snapping to a focal-length catalogue) with the same loss; the last held-out
reconstruction is checked not to be all zero or constant (``final_volume_trivial``).

The design returned is the last point (not the step of the lowest training loss, unlike
:func:`.gradient.optimize_psf`): each step's loss is on a new batch and the reconstruction
weights change with the optics, so the lowest one does not pick a better design, and the
weights of past steps are not kept. For the same reason end-to-end runs are not resumable
(neither the weights nor the optimiser state are stored): an existing study name is refused.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import torch
from torch import nn

from lfm_studio.engine.design import Design
from lfm_studio.engine.design.space import DesignSpace
from lfm_studio.engine.dtypes import real_dtype_named
from lfm_studio.engine.learned.data import Sample, Split, TrainingDataSpec, make_sample
from lfm_studio.engine.learned.losses import training_loss, trivial_reason
from lfm_studio.engine.learned.models.unrolled_rl import UnrolledRL
from lfm_studio.engine.optimize.candidate import EvaluationSettings
from lfm_studio.engine.optimize.constraints import Constraint, FocalLengthCatalogue
from lfm_studio.engine.optimize.gradient import (
    GRADIENT_TOLERANCE,
    DescentSetup,
    GradientResult,
    StartGradientCheck,
    check_dtype,
    descend,
    design_at,
    finish_study,
    open_recorder,
    prepare_start,
    snap_result,
)
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.reconstruct.unrolled import richardson_lucy_unrolled
from lfm_studio.engine.simulation import ImagingSetup
from lfm_studio.engine.systems.kinds_base import Projector
from lfm_studio.engine.systems.kinds_conventional import CONVENTIONAL
from lfm_studio.engine.systems.kinds_fourier import shift_invariant_lateral, shift_invariant_setup

RECONSTRUCTIONS: tuple[str, ...] = ("unrolled-rl", "rl")
DEFAULT_DATA = TrainingDataSpec(phantoms="beads", objects=(4, 10), photons=(2e4,), read_noise=1.0)
"""Training phantoms when none are given: 4-10 beads per volume, 2e4 photons per image."""


def sample_loss(
    sample: Sample,
    projector: Projector,
    reconstruct: Callable[[torch.Tensor, Projector], torch.Tensor],
    high_pass_weight: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(loss, volume)`` of one phantom: imaged through ``projector`` with the sample's noise held
    fixed (gradients reach the optics through the expected image), then reconstructed. The sample
    (CPU tensors, :func:`~lfm_studio.engine.learned.data.make_sample`) is moved to the projector's device."""
    truth = sample.truth.to(device=projector.device, dtype=projector.dtype)
    expected = projector.forward(truth)
    image = expected + (sample.image.to(device=projector.device, dtype=projector.dtype) - expected.detach())
    volume = reconstruct(image, projector)
    return training_loss(volume, truth, high_pass_weight), volume


def optimize_end_to_end(
    design: Design,
    space: DesignSpace,
    *,
    reconstruction: str = "unrolled-rl",
    freeze_optics: bool = False,
    freeze_reconstruction: bool = False,
    steps: int = 20,
    optimizer: str = "adam",
    lr: float = 0.05,
    lr_reconstruction: float = 0.01,
    schedule: str = "constant",
    dtype: str = "float32",
    iterations: int = 4,
    batch: int = 2,
    held_out: int = 4,
    data: TrainingDataSpec | None = None,
    high_pass_weight: float = 0.0,
    model: nn.Module | None = None,
    settings: EvaluationSettings | None = None,
    constraints: Sequence[Constraint] | None = None,
    catalogue: FocalLengthCatalogue | None = None,
    check_float64: bool = True,
    tolerance: float = GRADIENT_TOLERANCE,
    study: str | None = None,
    study_name: str = "lfm_study",
    seed: int = 0,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> GradientResult:
    """Train the optics in ``space`` and a differentiable reconstruction jointly on a task loss.

    Parameters (those shared with :func:`.gradient.optimize_psf` mean the same)
    ----------
    reconstruction : "unrolled-rl" (learned, :class:`UnrolledRL` with ``iterations`` steps; pass
        ``model`` to start from a trained one) or "rl" (plain unrolled RL, ``iterations`` steps;
        nothing to train, so the reconstruction is frozen).
    freeze_optics, freeze_reconstruction : keep that side fixed (not both).
    lr, lr_reconstruction : learning rates of the optics (fraction of each range) and of the
        reconstruction weights (Adam; L-BFGS takes one group with ``lr``).
    batch : training phantoms per step; held_out : test phantoms scored at the start and the end.
    data : the phantoms and photon budget (default :data:`DEFAULT_DATA` with ``seed``).
    seed : seeds the phantoms (unless ``data`` is given) and the new unrolled RL's initial weights.
    high_pass_weight : the high-pass term of the loss (0: plain energy-normalised MSE, floor 1).

    Returns
    -------
    :class:`.gradient.GradientResult`: ``start_value`` / ``final_value`` are the training loss of
    the first step and of the last, each measured at its step's point before the update
    (``final_value_at`` is ``"before_last_update"``: nothing is measured on training batches at the
    final design); ``extra`` holds ``held_out_start`` and ``held_out_final`` (the held-out loss at
    the start and at the final design: the numbers to compare), ``held_out_snapped``, ``zero_floor``, ``final_volume_trivial``, ``reconstruction_change`` (L2 norm
    of the change of the reconstruction weights) and the settings; ``model``
    is the (trained) reconstruction, None for "rl".
    """
    if reconstruction not in RECONSTRUCTIONS:
        raise ValueError(f"reconstruction must be one of {RECONSTRUCTIONS}; got {reconstruction!r}.")
    check_dtype(dtype)
    if reconstruction == "rl":
        freeze_reconstruction = True
    if freeze_optics and freeze_reconstruction:
        raise ValueError(
            "nothing to optimise: the optics and the reconstruction are both frozen (plain 'rl' has no "
            "weights). Fix: unfreeze one side, or use reconstruction='unrolled-rl'."
        )
    if not (isinstance(batch, int) and batch >= 1 and isinstance(held_out, int) and held_out >= 1):
        raise ValueError(f"batch and held_out must be integers >= 1; got {batch!r}, {held_out!r}.")
    spec = data or replace(DEFAULT_DATA, seed=seed)
    start = prepare_start(design, space, constraints)
    binding, u0 = start.binding, start.u
    base = settings or EvaluationSettings.for_design(design)
    conventional = binding.kind is CONVENTIONAL

    def setup_of(stack: PSFStack) -> ImagingSetup:
        return (
            CONVENTIONAL.imaging_setup(stack)
            if conventional
            else shift_invariant_setup(stack, lateral=lateral)
        )

    def setup_at(values: torch.Tensor, at: Design, precision: str) -> ImagingSetup:
        return setup_of(binding.psf_stack(at, values, replace(base, dtype=precision)))

    with torch.no_grad():
        start_stack = binding.psf_stack(design, binding.values(u0), replace(base, dtype=dtype))
    lateral = 0 if conventional else shift_invariant_lateral(start_stack)
    start_setup = setup_of(start_stack)
    net: nn.Module | None = None
    if reconstruction == "unrolled-rl":
        if model is not None:
            net = model
        else:  # initial weights drawn from ``seed``: the run repeats (the caller's RNG is left as it was)
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(seed)
                net = UnrolledRL(start_setup.projector, iterations=iterations)
        net = net.to(device=start_setup.projector.device, dtype=start_setup.projector.dtype)
        net.requires_grad_(not freeze_reconstruction)

    def reconstructor(network: nn.Module | None) -> Callable[[torch.Tensor, Projector], torch.Tensor]:
        if network is None:
            return lambda image, projector: richardson_lucy_unrolled(
                projector, image.clamp_min(0.0), iterations
            )
        return lambda image, projector: network(image, projector=projector)

    def batch_loss(
        setup: ImagingSetup, samples: Sequence[Sample], network: nn.Module | None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        losses, volume = [], None
        for sample in samples:
            loss, volume = sample_loss(sample, setup.projector, reconstructor(network), high_pass_weight)
            losses.append(loss)
        assert volume is not None
        return torch.stack(losses).mean(), volume

    def samples_of(setup: ImagingSetup, split: Split, start: int, count: int) -> list[Sample]:
        return [make_sample(spec, setup, split, start + i) for i in range(count)]

    def held_out_of(setup: ImagingSetup) -> tuple[float, torch.Tensor]:
        with torch.no_grad():
            loss, volume = batch_loss(setup, samples_of(setup, "test", 0, held_out), net)
        return float(loss), volume

    def held_out_loss(values: torch.Tensor, at: Design) -> tuple[float, torch.Tensor]:
        with torch.no_grad():
            return held_out_of(setup_at(values, at, dtype))

    start_held_out, _ = held_out_of(start_setup)  # the start PSF is computed once
    check = None
    if check_float64:
        check_samples = samples_of(start_setup, "train", 0, batch)

        def fresh(precision: str) -> tuple[torch.Tensor, list[torch.Tensor]]:
            leaf = u0.clone().requires_grad_(True)
            network = (
                None
                if net is None
                else copy.deepcopy(net).to(real_dtype_named(precision)).requires_grad_(True)
            )
            setup = setup_at(binding.values(leaf), design, precision)
            loss, _ = batch_loss(setup, check_samples, network)
            weights = [] if network is None else list(network.parameters())
            return loss.to(torch.float64), [leaf, *weights]

        # Step 0 evaluates the start gradient in ``dtype`` on the same batch (train samples 0..batch-1):
        # reused when it differentiates the same leaves (the optics and every reconstruction weight).
        check = StartGradientCheck(
            fresh, dtype, tolerance, reuse=not freeze_optics and (net is None or not freeze_reconstruction)
        )

    def loss_at(u: torch.Tensor, step: int) -> torch.Tensor:
        setup = setup_at(binding.values(u), design, dtype)
        with torch.no_grad():
            samples = samples_of(setup, "train", step * batch, batch)
        loss, _ = batch_loss(setup, samples, net)
        return loss.to(torch.float64)

    options = {
        "reconstruction": reconstruction,
        "freeze_optics": freeze_optics,
        "freeze_reconstruction": freeze_reconstruction,
        "optimizer": optimizer,
        "lr": lr,
        "lr_reconstruction": lr_reconstruction,
        "schedule": schedule,
        "steps": steps,
        "iterations": iterations,
        "batch": batch,
        "held_out": held_out,
        "high_pass_weight": high_pass_weight,
        "data": spec.to_dict(),
    }
    recorder = open_recorder(
        study, study_name, design=design, space=space,
        objective={"name": "task_loss", "unit": "", "direction": "minimize"},
        run_settings=replace(base, dtype=dtype), options=options, seed=seed,
    )  # fmt: skip
    u = u0.clone().requires_grad_(not freeze_optics)
    extra_groups = (
        []
        if net is None or freeze_reconstruction
        else [{"params": list(net.parameters()), "lr": lr_reconstruction}]
    )
    setup = DescentSetup(
        binding, design, steps, optimizer, lr, schedule, start.constraints, freeze_optics, extra_groups,
        recorder, progress, cancel, "minimize", on_first_gradient=None if check is None else check.take,
    )  # fmt: skip
    initial = [] if net is None else [p.detach().clone() for p in net.parameters()]
    history = descend(setup, u, loss_at)
    change = (
        0.0
        if net is None
        else sum(float((p.detach() - q).pow(2).sum()) for p, q in zip(net.parameters(), initial, strict=True))
    )
    final_values, last_point = binding.values_and_point(u)
    final, notes = design_at(binding, design, last_point)
    final_held_out, volume = held_out_loss(final_values, design)
    result = GradientResult(
        final, start.design, history, history[0].value, history[-1].value,
        check=None if check is None else check.result(), final="last", final_point=last_point,
        last_point=last_point, final_value_at="before_last_update",
    )  # fmt: skip
    result.extra = {
        "held_out_start": start_held_out,
        "held_out_final": final_held_out,
        "zero_floor": 1.0 + high_pass_weight,
        "final_volume_trivial": trivial_reason(volume),
        "reconstruction_change": math.sqrt(change),
        **options,
    }
    result.model = net
    result.warnings = notes
    snap_result(result, binding, catalogue, lambda values, snapped: held_out_loss(values, snapped)[0])
    if catalogue is not None:
        result.extra["held_out_snapped"] = result.snapped_value
    return finish_study(result, recorder)
