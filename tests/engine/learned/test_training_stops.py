"""Why and where :func:`~lfm_studio.engine.learned.train.train` stops, and what it keeps.

Early stopping on the validation loss (``patience`` validations without improvement), the best
validated weights kept and written (not the last ones), the time budget (an injected clock: no
wall-clock duration is asserted) and a resumed run counting from the checkpoint's step count and
best validation loss. The validation losses are scripted where the test needs a known sequence
(``train.validation_loss`` replaced), so the outcome does not depend on what a few steps learn.
"""

from __future__ import annotations

import importlib
import math

import pytest
import torch

from lfm_studio.engine.learned import models as model_registry
from lfm_studio.engine.learned.checkpoint import read_checkpoint
from lfm_studio.engine.learned.data import TrainingDataSpec
from lfm_studio.engine.learned.models import UnrolledRL
from lfm_studio.engine.learned.train import train

train_module = importlib.import_module(
    "lfm_studio.engine.learned.train"
)  # the package's `train` is the function
DATA = TrainingDataSpec(seed=1)
FEW = 2  # validation samples (the default 8 only costs time here)


@pytest.fixture
def built(monkeypatch):
    """The networks train() builds (the default model, recorded so the test can read its weights)."""
    networks: list[torch.nn.Module] = []

    def recording(projector, **config):
        networks.append(UnrolledRL(projector, **config))
        return networks[-1]

    monkeypatch.setitem(model_registry.MODELS, "unrolled-rl", recording)
    return networks


def _script(monkeypatch, values):
    """Make train()'s validation losses ``values``, in order; returns the list of calls made."""
    calls: list[float] = []
    values = iter(values)

    def scripted(model, samples, high_pass_weight):
        calls.append(next(values))
        return calls[-1]

    monkeypatch.setattr(train_module, "validation_loss", scripted)
    return calls


def _weights(network):
    return {name: tensor.detach().clone() for name, tensor in network.state_dict().items()}


def _same(a, b):
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


def test_early_stopping_keeps_and_writes_the_best_validated_weights_not_the_last(
    fourier, tmp_path, built, monkeypatch
):
    # first the starting point, then a validation every 2 steps: best at step 4, then 3 worse ones
    _script(monkeypatch, [1.0, 0.9, 0.7, 0.8, 0.75, 0.9, 0.1])
    snapshots = {}
    path = tmp_path / "m.safetensors"
    result = train(
        fourier.setup, data=DATA, max_steps=50, validate_every=2, patience=3, validation_size=FEW, checkpoint=path,
        on_step=lambda step, loss, checked: snapshots.update({step: _weights(built[0])}),
    )  # fmt: skip
    assert result.stop_reason == "early stopping"
    assert [step for step, _, _ in result.history] == list(range(1, 11))  # long before max_steps
    checked = [(step, value) for step, _, value in result.history if not math.isnan(value)]
    assert checked == [(2, 0.9), (4, 0.7), (6, 0.8), (8, 0.75), (10, 0.9)]
    training = result.header.training
    assert training["stop_reason"] == "early stopping" and training["steps"] == 10
    assert training["best_validation"] == 0.7
    assert not _same(snapshots[4], snapshots[10])  # the weights did move after the best
    assert _same(_weights(result.model), snapshots[4])  # the returned model: step 4's weights
    header, tensors = read_checkpoint(path)
    assert _same(tensors, snapshots[4])  # and the file on disk
    assert header.training["stop_reason"] == "early stopping" and header.training["best_validation"] == 0.7


def test_the_time_budget_stops_the_run_on_the_injected_clock(fourier, tmp_path, built):
    now = [100.0]  # seconds; each training step "takes" 25 s on this clock

    def on_step(step, loss, checked):
        now[0] += 25.0

    result = train(
        fourier.setup, data=DATA, budget_minutes=1.0, max_steps=20, validate_every=2, patience=100, validation_size=FEW,
        checkpoint=tmp_path / "m.safetensors", clock=lambda: now[0], on_step=on_step,
    )  # fmt: skip
    # 0, 25, 50 s are inside the 60 s budget, so steps 1-3 run; the check after step 3 (75 s) stops it
    # (max_steps=20 only ends a run whose budget check broke)
    assert result.stop_reason == "time budget"
    assert [step for step, _, _ in result.history] == [1, 2, 3]
    training = read_checkpoint(tmp_path / "m.safetensors")[0].training
    assert training["stop_reason"] == "time budget" and training["steps"] == 3
    assert training["seconds"] == 75.0  # the run's time on the injected clock


def test_a_budget_spent_before_the_first_step_keeps_the_starting_model(fourier, built):
    ticks = iter(range(10**6))  # any clock that moves forward: 1 s per reading
    result = train(
        fourier.setup,
        data=DATA,
        budget_minutes=1e-6,
        max_steps=50,
        validation_size=FEW,
        clock=lambda: float(next(ticks)),
    )
    assert result.stop_reason == "time budget" and result.history == []
    assert result.header.training["steps"] == 0
    torch.manual_seed(0)  # train()'s seed: the untrained network it started from
    assert _same(_weights(result.model), _weights(UnrolledRL(fourier.setup.projector)))


def test_resume_counts_steps_and_the_best_loss_from_the_checkpoint(fourier, tmp_path, built, monkeypatch):
    path = tmp_path / "m.safetensors"
    first = train(
        fourier.setup, data=DATA, max_steps=3, validate_every=3, validation_size=FEW, checkpoint=path
    )
    best, before = first.header.training["best_validation"], read_checkpoint(path)[1]
    assert first.header.training["steps"] == 3
    # every validation of the resumed run is worse than the checkpoint's best
    calls = _script(monkeypatch, [best + 1.0] * 10)
    resumed = train(
        fourier.setup,
        data=DATA,
        max_steps=50,
        validate_every=1,
        patience=2,
        validation_size=FEW,
        checkpoint=path,
        resume=True,
    )
    assert [step for step, _, _ in resumed.history] == [4, 5]  # numbered on from the checkpoint's 3
    assert len(calls) == 2  # no fresh starting validation: the checkpoint's best is the one to beat
    assert resumed.stop_reason == "early stopping"
    header, tensors = read_checkpoint(path)
    assert header.training["steps"] == 5 and header.training["best_validation"] == best
    assert _same(tensors, before)  # nothing better was found: the resumed weights are what is kept
    assert _same(_weights(resumed.model), before)
    assert resumed.header.training == header.training


def test_a_budget_stop_validates_the_steps_since_the_last_validation(fourier, tmp_path, built, monkeypatch):
    """Steps trained after the last scheduled validation are scored when the budget ends the run,
    and the header names the step whose weights the file holds."""
    _script(monkeypatch, [1.0, 0.9, 0.5])  # start, step 2 (scheduled), step 3 (at the budget stop)
    now = [0.0]
    snapshots = {}

    def on_step(step, loss, checked):
        now[0] += 25.0
        snapshots[step] = _weights(built[0])

    path = tmp_path / "m.safetensors"
    result = train(
        fourier.setup, data=DATA, budget_minutes=1.0, max_steps=20, validate_every=2, patience=100, validation_size=FEW,
        checkpoint=path, clock=lambda: now[0], on_step=on_step,
    )  # fmt: skip
    assert result.stop_reason == "time budget"
    values = [value for _, _, value in result.history]
    assert [step for step, _, _ in result.history] == [1, 2, 3]
    assert math.isnan(values[0]) and values[1:] == [0.9, 0.5]  # step 3 was scored at the stop
    header, tensors = read_checkpoint(path)
    assert header.training["best_validation"] == 0.5 and header.training["best_step"] == 3
    assert header.training["steps"] == 3
    assert _same(tensors, snapshots[3])  # the last step's weights were the best: kept, not dropped
