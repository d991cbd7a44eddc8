"""The reconstruction registry: schemas check options by name, claims hold, new methods plug in."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from lfm_studio.engine.operators import ShiftInvariantProjector
from lfm_studio.engine.reconstruct import reconstruct_frame, registry
from lfm_studio.engine.systems.kinds import CONVENTIONAL
from tests import toy_method


class DenseProjector:
    """A projector that is a plain matrix (no OTF: not shift-invariant), float64."""

    def __init__(
        self, matrix: torch.Tensor, volume_shape: tuple[int, int, int], image_shape: tuple[int, int]
    ):
        self.matrix, self.volume_shape, self.image_shape = matrix, volume_shape, image_shape
        self.device, self.dtype = matrix.device, matrix.dtype

    def forward(self, volume: torch.Tensor) -> torch.Tensor:
        return (self.matrix @ volume.reshape(-1)).reshape(self.image_shape)

    def adjoint(self, image: torch.Tensor) -> torch.Tensor:
        return (self.matrix.T @ image.reshape(-1)).reshape(self.volume_shape)


@pytest.fixture
def small():
    """A 2 x 6 x 6 volume on a 12 x 12 camera through random PSFs (float64), and a frame of it."""
    g = torch.Generator().manual_seed(0)
    projector = ShiftInvariantProjector(torch.rand(2, 12, 12, generator=g, dtype=torch.float64), (6, 6))
    truth = torch.rand(projector.volume_shape, generator=g, dtype=torch.float64)
    return projector, projector.forward(truth).detach() + 0.5


def test_the_builtin_methods_and_the_default():
    assert registry.names()[:4] == ["rl", "rl-accelerated", "wiener", "tikhonov"]
    assert registry.default_method() == "rl-accelerated" and registry.default_method() in registry.names()
    for method in registry.methods():
        assert method.options[0] is registry.BACKGROUND  # every method takes the background
        assert method.description and method.label
        method.resolve({})  # the defaults pass the schema


@pytest.mark.parametrize(
    ("method", "options", "expected"),
    [
        ("rl", {"iterations": 0}, r"iterations must be an integer >= 1; got 0\. Fix: e\.g\. iterations=30"),
        ("rl", {"iterations": 2.5}, "iterations must be an integer >= 1; got 2.5"),
        ("rl", {"iterations": True}, "iterations must be an integer >= 1; got True"),
        ("rl", {"rtol": 0.0}, r"rtol must be a finite number > 0 or None; got 0\.0"),
        ("rl", {"tv_weight": 0.3}, r"tv_weight must be a finite number >= 0 and < 0\.211"),
        (
            "rl",
            {"background": -1.0},
            r"background must be a finite number >= 0 \(photons per pixel\); got -1\.0",
        ),
        ("rl", {"background": math.nan}, "background must be a finite number >= 0"),
        ("wiener", {"snr": 0.0}, "snr must be a finite number > 0; got 0.0"),
        ("wiener", {"snr": math.inf}, "snr must be a finite number > 0; got inf"),
        ("tikhonov", {"refine": -1}, "refine must be an integer >= 0; got -1"),
        (
            "tikhonov",
            {"mu": 1e-3},
            r"method 'tikhonov' takes no option 'mu'; its options are background, snr, refine",
        ),
    ],
)
def test_bad_options_are_named_with_a_fix(method, options, expected):
    with pytest.raises(ValueError, match=expected) as caught:
        registry.get(method).resolve(options)
    assert "Fix:" in str(caught.value)


def test_resolve_fills_defaults_and_converts():
    got = registry.get("rl").resolve({"iterations": 5.0, "background": 2})
    assert got == {"background": 2.0, "iterations": 5, "rtol": None, "tv_weight": 0.0}
    assert isinstance(got["iterations"], int) and isinstance(got["background"], float)
    assert registry.get("tikhonov").resolve({})["snr"] == 1000.0  # mu = 1e-3, the engine's default
    numpy_values = registry.get("rl").resolve({"iterations": np.int64(4), "background": np.float32(0.5)})
    assert numpy_values["iterations"] == 4 and type(numpy_values["iterations"]) is int
    assert type(numpy_values["background"]) is float


def test_differentiable_claims_hold(small):
    """A method that says it is differentiable passes gradcheck from the frame to the volume."""
    projector, frame = small
    # "learned" needs a checkpoint for this projector: its gradcheck is in tests/engine/learned.
    claimed = [m for m in registry.methods() if m.differentiable and m.name != "learned"]
    assert {m.name for m in claimed} >= {"rl", "wiener", "tikhonov"}
    weights = torch.linspace(0.5, 1.5, math.prod(projector.volume_shape), dtype=torch.float64)
    for method in claimed:
        options = {"iterations": 3, "background": 0.5} if method.iterative else {"background": 0.1}

        def loss(y, method=method, options=options):
            return (method(projector, y, options) * weights.reshape(projector.volume_shape)).sum()

        with warnings.catch_warnings():  # the input guards read float(y) of a tensor that requires grad
            warnings.filterwarnings("ignore", message="Converting a tensor with requires_grad")
            assert torch.autograd.gradcheck(loss, (frame.clone().requires_grad_(True),), eps=1e-6, atol=1e-5)


def test_a_shift_invariant_method_refuses_another_projector_and_names_the_fix(small):
    projector, frame = small
    dense = DenseProjector(
        torch.rand(144, 72, dtype=torch.float64), projector.volume_shape, projector.image_shape
    )
    assert registry.get("rl").supports(dense) and not registry.get("wiener").supports(dense)
    with pytest.raises(
        ValueError,
        match=r"method 'wiener' \(Wiener \(one step\)\) needs a laterally shift-invariant.*Fix: choose rl, rl-accelerated",
    ):
        reconstruct_frame(dense, frame, method="wiener")
    volume = reconstruct_frame(dense, frame, method="rl", iterations=2)
    assert volume.shape == projector.volume_shape and bool(torch.isfinite(volume).all())


def test_the_refusal_lists_every_method_that_takes_the_projector(conventional):
    """A conventional LFM's lenslet-lattice projector: Wiener refuses it, and the fix names Tikhonov
    (which runs there, per lattice frequency) beside the methods that take any projector."""
    projector = conventional.setup64.projector
    takers = [m.name for m in registry.methods() if m.supports(projector)]
    assert "tikhonov" in takers and "wiener" not in takers and "rl" in takers
    with pytest.raises(ValueError, match="needs a laterally shift-invariant") as refused:
        reconstruct_frame(projector, torch.ones(projector.image_shape, dtype=torch.float64), method="wiener")
    assert str(refused.value).endswith(f"Fix: choose {', '.join(takers)}.")
    assert "Projector" not in str(refused.value)  # no internal class name: the user's words
    assert "got a conventional-LFM projector" in str(refused.value)
    kind_takers = [m.name for m in registry.methods() if m.supports_kind(CONVENTIONAL)]
    assert kind_takers == takers  # what the studio offers for a conventional design
    volume = reconstruct_frame(
        projector, projector.forward(torch.ones(projector.volume_shape)), method="tikhonov"
    )
    assert volume.shape == projector.volume_shape and bool(torch.isfinite(volume).all())


def test_a_registered_method_runs_by_name_and_leaves_again(small):
    projector, frame = small
    with toy_method.registered() as method:
        assert toy_method.NAME in registry.names() and registry.get(toy_method.NAME) is method
        assert [o.name for o in method.options] == ["background", "scale"]  # the background was added
        got = reconstruct_frame(projector, frame, method=toy_method.NAME, background=0.5, scale=2.0)
        sensitivity = projector.adjoint(torch.ones_like(frame))
        torch.testing.assert_close(got, 2.0 * projector.adjoint((frame - 0.5).clamp_min(0)) / sensitivity)
        with pytest.raises(ValueError, match="is registered already"):
            registry.register(toy_method.METHOD)
        assert "scale" in registry.all_options()
    assert toy_method.NAME not in registry.names() and "scale" not in registry.all_options()


def test_an_option_that_means_two_things_is_refused():
    clash = registry.Option("iterations", float, 1.0, "not a count", units="s")
    method = registry.Method("clash", "Clash", "one line", (clash,), toy_method.backprojection)
    with pytest.raises(
        ValueError, match=r"option 'iterations' is a float in s, but method 'rl' has it as a int"
    ):
        registry.register(method)
    assert "clash" not in registry.names()


@pytest.mark.parametrize(
    ("kwargs", "expected"),
    [
        ({"name": "two words"}, "non-empty word"),
        ({"projectors": "conventional"}, "projectors must be one of"),
        ({"devices": ("tpu",)}, "devices must be a non-empty subset"),
        ({"iterative": True}, "no 'iterations' option"),
    ],
)
def test_a_malformed_method_is_refused(kwargs, expected):
    base = {"name": "m", "label": "M", "description": "d", "options": (), "run": toy_method.backprojection}
    with pytest.raises(ValueError, match=expected):
        registry.Method(**{**base, **kwargs})


def test_an_option_default_outside_its_bounds_is_refused():
    with pytest.raises(ValueError, match=r"the default of iterations must be an integer >= 1; got 0"):
        registry.Option("iterations", int, 0, "count", minimum=1)
