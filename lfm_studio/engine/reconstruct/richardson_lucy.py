"""3D layered Richardson-Lucy (thesis eqs. 4.11-4.12) over any projector, as a generator of iterates.

With ``y`` the camera image (photons, baseline removed), ``b`` the background and ``A`` the projector
(``forward``: volume ``(Z, Y, X)`` -> image; ``adjoint``: image -> volume):

    x_{k+1} = x_k * A^T( y / (A x_k + b) ) / A^T 1

the EM algorithm for ``y ~ Poisson(A x + b)``: the Poisson negative log-likelihood
(:func:`poisson_nll`) never increases. ``A^T 1`` (the voxel sensitivity) is computed
once. Options (combinable):

- ``acceleration="biggs-andrews"``: vector extrapolation (:mod:`.accelerated`);
  ``acceleration="geometric"``: the same extrapolation of ``log x`` (fewer iterations);
- ``backprojector=``: an unmatched back projector ``B`` replacing ``A^T``, e.g.
  :func:`.wiener_butterworth_backprojector`. When ``B`` has the DC gain of ``A^T``
  (attribute ``uses_adjoint_sensitivity``) the update is written in residual form,
  ``x * (A^T 1 + B(y / (A x + b) - 1)) / A^T 1``: it equals RL for ``B = A^T`` and keeps
  ``y = A x + b`` a fixed point although ``B 1 != A^T 1`` near the window edges (dividing by
  ``B 1`` instead, as the plain form would, divided by values near 0 and diverged).
  Any other callable ``B`` gives ``x * B(y / (A x + b)) / B 1``;
- ``tv_weight=``: total-variation regularisation (:mod:`.total_variation`).

Numerics: ``A x + b`` and the sensitivity are floored at ``16 eps`` times their data
scale (:mod:`.guards`), the back-projected ratio is clipped at 0 (FFT rounding and the
negative lobes of unmatched back projectors), so estimates stay >= 0; estimate values
below the smallest normal number are set to 0 (no denormals). RL is scale covariant
(``y, b -> c y, c b`` gives ``x -> c x``), so the iterations run on the data divided by
the power of two nearest its largest value and the estimates are multiplied back
(exact in binary floating point): ``A x + b`` stays near 1 whatever the units, so with
data near float32's smallest normal number (1.2e-38) no voxel is flushed to 0 during the
iterations; only result values below it are 0.

Start (``initial=None``): the uniform volume whose projection carries the image's
photons, ``x_0 = sum(y - b) / sum(A^T 1)`` in every voxel (RL keeps that total after
its first step when ``b = 0``).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, TypedDict

import torch

from lfm_studio.engine.operators.protocol import Projector, missing_members
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint
from lfm_studio.engine.reconstruct.accelerated import NLL_SLACK, BiggsAndrews, GeometricExtrapolation
from lfm_studio.engine.reconstruct.guards import (
    check_background,
    check_estimate,
    check_image,
    check_iterations,
    check_rtol,
    check_sensitivity,
    check_signal,
    floored,
    working_dtype_device,
)
from lfm_studio.engine.reconstruct.total_variation import check_tv_weight, tv_denominator
from lfm_studio.engine.types import Scalar, Shape3, TensorLike

if TYPE_CHECKING:
    from typing_extensions import Unpack

Acceleration = Literal["biggs-andrews", "geometric"]
#: Extrapolation state per ``acceleration`` name (no entry for ``None``: plain RL).
ACCELERATIONS: dict[str, Callable[[], BiggsAndrews]] = {
    "biggs-andrews": BiggsAndrews,
    "geometric": GeometricExtrapolation,
}
#: A back projector ``image (Py, Px) -> volume (Z, Y, X)`` replacing ``A^T`` (e.g.
#: :class:`~.backprojectors.FilteredBackProjector`); one with ``uses_adjoint_sensitivity = True``
#: has the DC gain of ``A^T`` and is applied in residual form (module notes).
BackProjector = Callable[[torch.Tensor], torch.Tensor]


class RLOptions(TypedDict, total=False):
    """Keyword options of :func:`richardson_lucy_iterates` (all optional; see its parameters)."""

    background: Scalar
    initial: torch.Tensor | None
    iterations: int
    rtol: float | None
    acceleration: Acceleration | None
    backprojector: BackProjector | None
    tv_weight: float
    track_nll: bool
    progress: ProgressCallback | None
    cancel: CancelToken


@dataclass(frozen=True)
class Iterate:
    """One Richardson-Lucy iterate.

    Attributes
    ----------
    index : int
        Number of updates done (1 for the first).
    estimate : tensor ``(Z, Y, X)``
        The volume after ``index`` updates (a fresh tensor; later iterations do not modify it).
    relative_change : float
        ``||x_index - x_(index-1)|| / ||x_(index-1)||``.
    nll : float or None
        Poisson negative log-likelihood of ``estimate`` (``track_nll=True``), else ``None``.
    alpha : float
        Biggs-Andrews extrapolation factor used for this update (0 without acceleration).
    """

    index: int
    estimate: torch.Tensor
    relative_change: float
    nll: float | None = None
    alpha: float = 0.0


class _Problem:
    """Checked inputs of one reconstruction: image, background, back projector, sensitivity."""

    def __init__(
        self, projector: Projector, image: TensorLike, background: Scalar, backprojector: BackProjector | None
    ) -> None:
        if not isinstance(projector, Projector):
            raise TypeError(
                "projector must have forward, adjoint, volume_shape, image_shape, device and dtype "
                f"(the Projector protocol); {type(projector).__name__} has no "
                f"{', '.join(missing_members(projector, Projector))}. Fix: pass setup.projector "
                "(lfm_studio.engine.simulation.imaging_setup) or another engine projector."
            )
        self.projector = projector
        self.dtype, self.device = working_dtype_device(projector)
        shape = projector.image_shape
        image = check_image(image, shape, dtype=self.dtype, device=self.device)
        background = check_background(background, shape, dtype=self.dtype, device=self.device)
        check_signal(image, background)
        self.data_scale = _power_of_two_near(max(float(image.max()), float(background.max())))
        self.image = self.from_data_units(image)
        self.background = self.from_data_units(background)
        self.signal = float((self.image.double() - self.background.double()).sum())
        self.nll_slack = NLL_SLACK * float(self.image.double().sum())  # likelihood safeguard
        self.volume_shape: Shape3 = projector.volume_shape
        self.backproject: BackProjector = backprojector if backprojector is not None else projector.adjoint
        ones = torch.ones(shape, dtype=self.dtype, device=self.device)
        matched = backprojector is None or getattr(backprojector, "uses_adjoint_sensitivity", False)
        self.residual_form = backprojector is not None and matched
        self.sensitivity = self._volume((projector.adjoint if matched else self.backproject)(ones))
        check_sensitivity(self.sensitivity, "A^T 1" if matched else "B 1")
        self.sensitivity_scale = float(self.sensitivity.detach().abs().max())
        self.floored_sensitivity = floored(self.sensitivity, self.sensitivity_scale, self.dtype)  # once
        self.smallest_normal = torch.finfo(self.dtype).tiny
        self.image_scale = max(float(self.image.max()), float(self.background.max()))
        if matched:  # the sensitivity is A^T 1, and sum(A^T 1) = 1^T A 1: no extra projection
            self.flux = float(self.sensitivity.detach().double().sum())
        else:
            self.flux = float(
                self._image(projector.forward(torch.ones_like(self.sensitivity))).double().sum()
            )
        if not self.flux > 0:
            raise ValueError(
                f"the projector sends no light to the camera: sum(A 1) = {self.flux:.6g} (must be > 0). "
                "Fix: check the PSF stack (it may be all zero)."
            )

    def from_data_units(self, tensor: torch.Tensor) -> torch.Tensor:
        """``tensor`` (image counts or volume) divided by :attr:`data_scale`, exactly (a power of two)."""
        if self.data_scale == 1.0:
            return tensor
        return (tensor.double() / self.data_scale).to(self.dtype)

    def to_data_units(self, tensor: torch.Tensor) -> torch.Tensor:
        """A working estimate multiplied back by :attr:`data_scale` (a fresh tensor unless the scale
        is 1); values that fall below the smallest normal number there are 0 (no denormals)."""
        if self.data_scale == 1.0:
            return tensor
        scaled = tensor * self.data_scale
        return scaled.masked_fill(scaled < self.smallest_normal, 0.0) if self.data_scale < 1.0 else scaled

    def _volume(self, volume: torch.Tensor) -> torch.Tensor:
        if tuple(volume.shape) != self.volume_shape:
            raise ValueError(
                f"back projection gave shape {tuple(volume.shape)}; expected {self.volume_shape}."
            )
        return volume.to(device=self.device, dtype=self.dtype)

    def _image(self, image: torch.Tensor) -> torch.Tensor:
        return image.to(device=self.device, dtype=self.dtype)

    def predicted(self, volume: torch.Tensor) -> torch.Tensor:
        """``A x + b``, floored at the relative epsilon of the image scale."""
        return floored(
            self._image(self.projector.forward(volume)) + self.background, self.image_scale, self.dtype
        )

    def step(self, point: torch.Tensor, tv_weight: float, predicted: torch.Tensor | None) -> torch.Tensor:
        """One RL update from ``point``: ``point * max(B(y / (A point + b)), 0) / (B 1 [* TV term])``.

        ``predicted`` is ``A point + b`` when already known (saves a forward projection).
        """
        ratio = self.image / (self.predicted(point) if predicted is None else predicted)
        if self.residual_form:
            correction = (self.sensitivity + self._volume(self.backproject(ratio - 1.0))).clamp_min(0.0)
        else:
            correction = self._volume(self.backproject(ratio)).clamp_min(0.0)
        if tv_weight:
            denominator = floored(
                self.sensitivity * tv_denominator(point, tv_weight), self.sensitivity_scale, self.dtype
            )
        else:
            denominator = self.floored_sensitivity
        update = correction.mul_(point).div_(denominator)  # correction is a fresh tensor
        # Background voxels shrink geometrically; flush values below the smallest normal number (in
        # working and in data units) to 0 so they never turn denormal (denormal arithmetic is
        # 10-100x slower on x86 CPUs).
        return update.masked_fill(update < self.smallest_normal, 0.0)

    def initial(self) -> torch.Tensor:
        """Uniform volume at the flux-matching level ``sum(y - b) / sum(A^T 1)``."""
        level = self.signal / self.flux
        return torch.full(self.volume_shape, level, dtype=self.dtype, device=self.device)

    def working_nll(self, predicted: torch.Tensor) -> float:
        """``sum(m - y log m)`` in working units for ``predicted = m``, in float64 (comparisons only)."""
        mean = predicted.detach().double()
        return float((mean - torch.xlogy(self.image.double(), mean)).sum())

    def nll(self, predicted: torch.Tensor) -> float:
        """Poisson NLL ``sum(Ax + b - y log(Ax + b))`` in the data's units, from the working
        ``predicted = (Ax + b) / c``, in float64 (``c`` = :attr:`data_scale`).

        ``sum(c m - c y log(c m)) = c (sum(m - y log m) - log(c) sum(y))``; the constant
        ``sum(log y!)`` is dropped.
        """
        mean = predicted.detach().double()
        y = self.image.double()
        c = self.data_scale
        return c * float((mean - torch.xlogy(y, mean)).sum() - math.log(c) * y.sum())


def _power_of_two_near(value: float) -> float:
    """``2**e`` with ``value / 2**e`` in ``[1, 2)`` (1.0 for a value that is not > 0)."""
    if not value > 0.0:
        return 1.0
    return math.ldexp(1.0, math.frexp(value)[1] - 1)


def _norm(tensor: torch.Tensor) -> float:
    """L2 norm, in the tensor's dtype (fast) unless its squares may over/underflow there."""
    value = float(torch.linalg.vector_norm(tensor.detach()))
    if not 1e-15 < value < 1e15:  # float32 squares leave the normal range near 1e+-19
        value = float(torch.linalg.vector_norm(tensor.detach(), dtype=torch.float64))
    return value


def poisson_nll(
    projector: Projector, volume: TensorLike, image: TensorLike, *, background: Scalar = 0.0
) -> float:
    """Poisson negative log-likelihood ``sum(A x + b - y log(A x + b))`` of ``volume`` given ``image``.

    The constant ``sum(log y!)`` is dropped; ``A x + b`` is floored as in the RL update.
    """
    problem = _Problem(projector, image, background, None)
    x = check_estimate("volume", volume, problem.volume_shape, dtype=problem.dtype, device=problem.device)
    return problem.nll(problem.predicted(problem.from_data_units(x)))


def richardson_lucy_iterates(
    projector: Projector,
    image: TensorLike,
    *,
    background: Scalar = 0.0,
    initial: torch.Tensor | None = None,
    iterations: int = 30,
    rtol: float | None = None,
    acceleration: Acceleration | None = None,
    backprojector: BackProjector | None = None,
    tv_weight: float = 0.0,
    track_nll: bool = False,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
) -> Iterator[Iterate]:
    """Yield Richardson-Lucy iterates of ``image`` through ``projector``.

    Parameters
    ----------
    projector : Projector
        Any projector (``forward``, ``adjoint``, ``volume_shape`` ``(Z, Y, X)``, ``image_shape``,
        ``device``, ``dtype``) (shift-invariant Fourier LFM, conventional lenslet lattice, ...); the
        reconstruction runs on its device and in its dtype (float32 or float64).
    image : tensor or array ``(Py, Px)``
        Camera image in photons (>= 0, the camera's baseline removed): convert camera counts with
        :func:`lfm_studio.engine.io.counts_to_photons`. The volume is in photons per voxel.
    background : float or tensor broadcastable to ``(Py, Px)``
        Expected background photons per pixel ``b`` (>= 0), e.g. the noise floor
        :func:`~lfm_studio.engine.io.counts_to_photons` returns.
    initial : tensor ``(Z, Y, X)``, optional
        Starting volume (>= 0, not all zero); default: flux-matched uniform volume.
    iterations : int
        Maximum number of updates.
    rtol : float, optional
        Stop after the first iterate whose relative change is below ``rtol``.
    acceleration : None, ``"biggs-andrews"`` or ``"geometric"``
        Extrapolation between updates (:mod:`.accelerated`); ``"geometric"`` extrapolates
        ``log x`` and needs the fewest iterations.
    backprojector : callable ``image -> volume``, optional
        Unmatched back projector (e.g. :func:`wiener_butterworth_backprojector`).
    tv_weight : float
        Total-variation weight ``lambda`` in ``[0, 0.211)``; 0 disables it.
    track_nll : bool
        Report the Poisson NLL of each iterate. Plain RL reuses that forward projection in
        the next update (no extra cost); with acceleration it costs one forward projection.
    progress, cancel
        ``progress(done, total, message)`` after each update; ``cancel`` is checked before
        each update and raises :class:`~lfm_studio.engine.progress.CancelledError`.

    Returns
    -------
    iterator of Iterate
        Inputs are checked when this function is called (errors surface here, not at the
        first ``next``); the updates run as the iterator is consumed.
    """
    if acceleration is not None and acceleration not in ACCELERATIONS:
        raise ValueError(
            f"acceleration must be None, 'biggs-andrews' or 'geometric'; got {acceleration!r}. "
            "Fix: acceleration='geometric' for the fastest convergence."
        )
    iterations = check_iterations(iterations)
    rtol = check_rtol(rtol)
    tv_weight = check_tv_weight(tv_weight)
    problem = _Problem(projector, image, background, backprojector)
    if initial is None:
        x = problem.initial()
    else:
        x = problem.from_data_units(
            check_estimate(
                "initial", initial, problem.volume_shape, dtype=problem.dtype, device=problem.device
            )
        )
    return _iterate(problem, x, iterations, rtol, acceleration, tv_weight, track_nll, progress, cancel)


def _iterate(
    problem: _Problem,
    x: torch.Tensor,
    iterations: int,
    rtol: float | None,
    acceleration: Acceleration | None,
    tv_weight: float,
    track_nll: bool,
    progress: ProgressCallback | None,
    cancel: CancelToken,
) -> Iterator[Iterate]:
    """The update loop of :func:`richardson_lucy_iterates` on checked inputs."""
    extrapolation = ACCELERATIONS[acceleration]() if acceleration else None
    name = "accelerated Richardson-Lucy" if acceleration else "Richardson-Lucy"
    done, known = 0, None  # known: A x + b of the current x, when computed for the NLL
    for k in range(1, iterations + 1):
        checkpoint(cancel, progress, k - 1, iterations, f"{name}: iteration {k} of {iterations}")
        point = extrapolation.predict(x) if extrapolation else x
        predicted = known if point is x else None
        if extrapolation:
            point, predicted = _safeguarded(problem, extrapolation, x, point, predicted, known)
        update = problem.step(point, tv_weight, predicted)
        if extrapolation:
            extrapolation.record(x, point, update)
        change = _norm(update - x) / max(_norm(x), 1e-300)
        x, done = update, k
        known = problem.predicted(x) if track_nll else None
        nll = problem.nll(known) if known is not None else None
        yield Iterate(k, problem.to_data_units(x), change, nll, extrapolation.alpha if extrapolation else 0.0)
        if rtol is not None and change < rtol:
            break
    if progress is not None:
        progress(iterations, iterations, f"{name}: done after {done} iteration(s)")


def _safeguarded(
    problem: _Problem,
    extrapolation: BiggsAndrews,
    x: torch.Tensor,
    point: torch.Tensor,
    predicted: torch.Tensor | None,
    known: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The point this step starts from and its ``A point + b``: the extrapolated ``point`` unless
    its Poisson NLL is worse than the last starting point's, then ``x`` (likelihood safeguard,
    :mod:`.accelerated`; costs one extra forward projection when it rejects, none when ``known``,
    ``A x + b`` already computed for the NLL track, is given)."""
    if predicted is None:
        predicted = problem.predicted(point)
    nll = problem.working_nll(predicted)
    if point is not x and not extrapolation.accept(nll, problem.nll_slack):
        point, predicted = x, known if known is not None else problem.predicted(x)
        nll = problem.working_nll(predicted)
    extrapolation.started_at(nll)
    return point, predicted


def richardson_lucy(projector: Projector, image: TensorLike, **options: Unpack[RLOptions]) -> torch.Tensor:
    """The last estimate of :func:`richardson_lucy_iterates` (same arguments), shape ``(Z, Y, X)``."""
    estimate = None
    for iterate in richardson_lucy_iterates(projector, image, **options):
        estimate = iterate.estimate
    assert estimate is not None  # iterations >= 1
    return estimate
