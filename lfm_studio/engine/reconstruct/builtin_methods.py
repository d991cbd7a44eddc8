"""The built-in reconstruction methods, registered in :mod:`.registry`: rl, rl-accelerated, wiener, tikhonov.

Richardson-Lucy takes any projector and models the background; Wiener takes a shift-invariant
(Fourier LFM) projector and Tikhonov also a conventional-LFM lenslet-lattice one; both are
linear and invert the frame minus the background, not clipped (:func:`_signal`). "rl-accelerated"
is :func:`.accelerated_rl_options` (geometric extrapolation with a likelihood safeguard); its
extrapolation step is not differentiable (a ``gradcheck`` through it fails), plain RL's is.
Total-variation regularisation (:mod:`.total_variation`) is the RL option ``tv_weight``.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping

import torch

from lfm_studio.engine.operators.protocol import Projector
from lfm_studio.engine.progress import CancelToken, ProgressCallback
from lfm_studio.engine.reconstruct.fourier_geometry import require_fourier_projector
from lfm_studio.engine.reconstruct.recommended import accelerated_rl_options
from lfm_studio.engine.reconstruct.registry import IteratesRun, Method, MethodRun, Option, Step, register
from lfm_studio.engine.reconstruct.richardson_lucy import RLOptions, richardson_lucy, richardson_lucy_iterates
from lfm_studio.engine.reconstruct.tikhonov import tikhonov
from lfm_studio.engine.reconstruct.total_variation import MAX_TV_WEIGHT
from lfm_studio.engine.reconstruct.wiener import wiener
from lfm_studio.engine.types import OptionValue

ITERATIONS = Option("iterations", int, 30, "Richardson-Lucy updates (at most)", minimum=1)
RTOL = Option(
    "rtol",
    float,
    None,
    "stop once the relative change of the estimate falls below this",
    minimum=0.0,
    exclusive_minimum=True,
    optional=True,
)
TV_WEIGHT = Option(
    "tv_weight",
    float,
    0.0,
    "total-variation regularisation weight (0: none; typically 0.001 to 0.02)",
    minimum=0.0,
    maximum=MAX_TV_WEIGHT,
    exclusive_maximum=True,
)
WIENER_SNR = Option(
    "snr", float, 100.0, "Wiener: power signal-to-noise ratio", minimum=0.0, exclusive_minimum=True
)
TIKHONOV_SNR = Option(
    "snr", float, 1000.0, "Tikhonov: regularisation mu = 1 / snr", minimum=0.0, exclusive_minimum=True
)
REFINE = Option(
    "refine", int, 0, "conjugate-gradient steps on the exact normal equations (0: closed form)", minimum=0
)


def _number(options: Mapping[str, OptionValue], name: str) -> float:
    value = options[name]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name} must be a number; got {value!r}.")
    return float(value)


def _rl_arguments(projector: Projector, options: Mapping[str, OptionValue], accelerated: bool) -> RLOptions:
    """The keyword arguments of :func:`richardson_lucy_iterates` for checked registry ``options``."""
    rtol = options["rtol"]
    arguments: RLOptions = {
        "background": _number(options, "background"),
        "iterations": int(_number(options, "iterations")),
        "rtol": None if rtol is None else _number(options, "rtol"),
        "tv_weight": _number(options, "tv_weight"),
    }
    if accelerated:
        arguments.update(accelerated_rl_options(projector))
    return arguments


def _rl_iterates(accelerated: bool) -> IteratesRun:
    def iterates(
        projector: Projector,
        frame: torch.Tensor,
        options: Mapping[str, OptionValue],
        progress: ProgressCallback | None,
        cancel: CancelToken,
    ) -> Iterator[Step]:
        arguments = _rl_arguments(projector, options, accelerated)
        arguments["progress"], arguments["cancel"] = progress, cancel
        return richardson_lucy_iterates(projector, frame, **arguments)

    return iterates


def _rl_run(accelerated: bool) -> MethodRun:
    def run(
        projector: Projector,
        frame: torch.Tensor,
        options: Mapping[str, OptionValue],
        progress: ProgressCallback | None,
        cancel: CancelToken,
    ) -> torch.Tensor:
        arguments = _rl_arguments(projector, options, accelerated)
        arguments["progress"], arguments["cancel"] = progress, cancel
        return richardson_lucy(projector, frame, **arguments)

    return run


def _signal(frame: torch.Tensor, options: Mapping[str, OptionValue]) -> torch.Tensor:
    """The frame minus the background, photons per pixel, NOT clipped at 0 (what the linear methods invert).

    The read noise left after removing the camera's noise floor (the ``background`` the front ends
    pass) is zero-mean; clipping it at 0 would keep only its positive half, about 0.4 sigma per
    pixel, which a linear inverse turns into large sheets of light of both signs (a noisy
    conventional-LFM image's Tikhonov volume then held 2.9x to 4.2x the truth's photons).
    """
    return frame - _number(options, "background")


def _wiener_run(
    projector: Projector,
    frame: torch.Tensor,
    options: Mapping[str, OptionValue],
    progress: ProgressCallback | None,
    cancel: CancelToken,
) -> torch.Tensor:
    del progress, cancel  # one step
    fourier = require_fourier_projector(projector, "Wiener deconvolution")
    return wiener(fourier, _signal(frame, options), snr=_number(options, "snr"))


def _tikhonov_run(
    projector: Projector,
    frame: torch.Tensor,
    options: Mapping[str, OptionValue],
    progress: ProgressCallback | None,
    cancel: CancelToken,
) -> torch.Tensor:
    del progress, cancel  # one step (plus ``refine`` CG steps)
    refine = int(_number(options, "refine"))
    return tikhonov(projector, _signal(frame, options), mu=1.0 / _number(options, "snr"), refine=refine)


BUILTIN = (
    Method(
        "rl",
        "Richardson-Lucy",
        "Richardson-Lucy: the Poisson maximum-likelihood EM iteration, any projector",
        (ITERATIONS, RTOL, TV_WEIGHT),
        _rl_run(False),
        differentiable=True,
        iterative=True,
        iterates=_rl_iterates(False),
    ),
    Method(
        "rl-accelerated",
        "Richardson-Lucy, accelerated",
        "Richardson-Lucy with geometric extrapolation and a likelihood safeguard: plain RL's quality in "
        "about a quarter of its iterations",
        (ITERATIONS, RTOL, TV_WEIGHT),
        _rl_run(True),
        iterative=True,
        iterates=_rl_iterates(True),
    ),
    Method(
        "wiener",
        "Wiener (one step)",
        "Wiener deconvolution per depth (shift-invariant Fourier LFM projectors): a quick preview; every "
        "depth holds the whole image's light, so not photons per voxel",
        (WIENER_SNR,),
        _wiener_run,
        differentiable=True,
        projectors="shift-invariant",
    ),
    Method(
        "tikhonov",
        "Tikhonov (one step)",
        "multi-depth Tikhonov per spatial frequency (Fourier LFM) or per lenslet-lattice frequency "
        "(conventional LFM)",
        (TIKHONOV_SNR, REFINE),
        _tikhonov_run,
        differentiable=True,
        projectors="periodic",
    ),
)


def register_builtin() -> None:
    """Register :data:`BUILTIN` (idempotent: already registered names are left as they are)."""
    from lfm_studio.engine.reconstruct.registry import is_registered

    for method in BUILTIN:
        if not is_registered(method.name):
            register(method)


register_builtin()
