"""Checkpoints (safetensors + header, refusals) and training runs (floors, resume, cancel, collapse)."""

from __future__ import annotations

import math

import pytest
import torch
from safetensors.torch import save_file

from lfm_studio.engine.image_quality import ncc
from lfm_studio.engine.learned import models as model_registry
from lfm_studio.engine.learned.checkpoint import header_for, load_model, save_checkpoint
from lfm_studio.engine.learned.data import TrainingDataSpec, make_samples
from lfm_studio.engine.learned.losses import trivial_reason
from lfm_studio.engine.learned.models import build_model
from lfm_studio.engine.learned.models.common import adjoint_normaliser
from lfm_studio.engine.learned.train import train
from lfm_studio.engine.progress import CancelledError
from lfm_studio.engine.reconstruct.unrolled import richardson_lucy_unrolled

DATA = TrainingDataSpec(seed=1)


def _perturbed(setup, name="unrolled-rl"):
    torch.manual_seed(3)
    model = build_model(name, setup.projector)
    with torch.no_grad():
        for parameter in model.parameters():
            parameter.add_(0.01 * torch.randn_like(parameter))
    return model


def test_a_checkpoint_round_trips_and_refuses_another_design_or_sampling(fourier, conventional, tmp_path):
    model = _perturbed(fourier.setup)
    header = header_for(
        "unrolled-rl", model.config, fourier.setup, "a" * 64, fourier.stack.depths, data=DATA.to_dict()
    )
    path = save_checkpoint(tmp_path / "m.safetensors", model, header)
    loaded, read = load_model(path, fourier.setup, design_hash="a" * 64, depths=fourier.stack.depths)
    image = make_samples(DATA, fourier.setup, "test", 1)[0].image
    with torch.no_grad():
        assert torch.equal(loaded(image), model(image))  # same weights, same code path
    assert read.data == DATA.to_dict() and read.depths == header.depths
    with pytest.raises(ValueError, match="trained for another design"):
        load_model(path, fourier.setup, design_hash="b" * 64)
    with pytest.raises(ValueError, match="trained for volume_shape"):
        load_model(path, conventional.setup)
    with pytest.raises(ValueError, match="trained for depths"):
        load_model(path, fourier.setup, depths=fourier.stack.depths[:-1])
    with pytest.raises(FileExistsError):
        save_checkpoint(path, model, header)


def test_foreign_files_are_named(tmp_path, fourier):
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"not a checkpoint at all")
    with pytest.raises(ValueError, match="not a safetensors file"):
        load_model(junk, fourier.setup)
    bare = tmp_path / "bare.safetensors"
    save_file({"w": torch.zeros(2)}, str(bare))
    with pytest.raises(ValueError, match="no lfm_studio header"):
        load_model(bare, fourier.setup)
    with pytest.raises(FileNotFoundError, match="no such checkpoint"):
        load_model(tmp_path / "missing.safetensors", fourier.setup)


def test_a_short_training_beats_the_back_projection_floor_and_is_not_trivial(fourier, tmp_path):
    setup = fourier.setup
    result = train(setup, data=DATA, max_steps=30, validate_every=10, checkpoint=tmp_path / "m.safetensors")
    test = make_samples(DATA, setup, "test", 4)
    _assert_beats_the_back_projection_floor(setup, result.model, test)
    assert result.header.training["steps"] == 30 and result.stop_reason == "steps"
    assert result.header.training["best_validation"] < result.header.training["zero_floor"]
    reloaded, _ = load_model(tmp_path / "m.safetensors", setup)
    with torch.no_grad():
        torch.testing.assert_close(reloaded(test[0].image), result.model(test[0].image))


def test_resume_continues_from_the_checkpoint_and_cancel_leaves_it_intact(fourier, tmp_path):
    path = tmp_path / "m.safetensors"
    train(fourier.setup, data=DATA, max_steps=4, validate_every=2, checkpoint=path)
    with pytest.raises(FileExistsError, match="already exists"):
        train(fourier.setup, data=DATA, max_steps=2, checkpoint=path)
    resumed = train(fourier.setup, data=DATA, max_steps=2, validate_every=2, checkpoint=path, resume=True)
    assert [step for step, _, _ in resumed.history] == [5, 6] and resumed.header.training["steps"] == 6
    before = path.read_bytes()
    with pytest.raises(CancelledError):
        train(fourier.setup, data=DATA, max_steps=2, checkpoint=path, resume=True, cancel=lambda: True)
    assert path.read_bytes() == before


class _Collapsing(torch.nn.Module):
    """A "model" that can only answer zero: training must refuse it."""

    def __init__(self, projector, **config):
        super().__init__()
        self.shape, self.config = tuple(projector.volume_shape), config
        self.weight = torch.nn.Parameter(torch.zeros(()))

    def forward(self, image):
        return torch.zeros(self.shape) * self.weight


def test_a_collapsed_model_is_refused_and_writes_nothing(fourier, tmp_path, monkeypatch):
    monkeypatch.setitem(model_registry.MODELS, "collapsing", _Collapsing)
    with pytest.raises(ValueError, match="all zero: a collapsed model"):
        train(
            fourier.setup, model="collapsing", data=DATA, max_steps=2, checkpoint=tmp_path / "m.safetensors"
        )
    assert not (tmp_path / "m.safetensors").exists()


class _Overshooting(torch.nn.Module):
    """Finite, not constant, and far too bright: worse than predicting nothing."""

    def __init__(self, projector, **config):
        super().__init__()
        self.projector, self.config = projector, config
        self.norm = adjoint_normaliser(projector)
        self.weight = torch.nn.Parameter(torch.ones(()))

    def forward(self, image):
        return 1e3 * self.weight * self.projector.adjoint(image.clamp_min(0.0)) / self.norm


class _NaNOnce(_Overshooting):
    """Right scale, but its first training step's output is NaN (the loss too)."""

    def __init__(self, projector, **config):
        super().__init__(projector, **config)
        self.calls = 0

    def forward(self, image):
        volume = self.weight * richardson_lucy_unrolled(self.projector, image.clamp_min(0.0), 3)
        self.calls += self.training
        return volume * float("nan") if self.training and self.calls == 1 else volume


def test_a_model_worse_than_the_all_zero_volume_is_refused_and_writes_nothing(fourier, tmp_path, monkeypatch):
    monkeypatch.setitem(model_registry.MODELS, "overshooting", _Overshooting)
    target = tmp_path / "m.safetensors"
    with pytest.raises(ValueError, match=r"not below the all-zero volume's 2: it reconstructs worse") as info:
        train(
            fourier.setup, model="overshooting", data=DATA, max_steps=2, validate_every=1, checkpoint=target
        )
    assert "Fix:" in str(info.value)
    assert not target.exists()  # not even a running checkpoint


class _NaNGradientOnce(_NaNOnce):
    """A finite loss whose first training step has a NaN gradient (d sqrt(u) / du at u = 0, times 0)."""

    def forward(self, image):
        volume = self.weight * richardson_lucy_unrolled(self.projector, image.clamp_min(0.0), 3)
        self.calls += self.training
        if self.training and self.calls == 1:
            return volume + 0.0 * torch.sqrt(self.weight - self.weight.detach())
        return volume


def test_a_finite_loss_with_a_non_finite_gradient_is_skipped_too(fourier, monkeypatch):
    monkeypatch.setitem(model_registry.MODELS, "nan-gradient", _NaNGradientOnce)
    result = train(fourier.setup, model="nan-gradient", data=DATA, max_steps=3, validate_every=3)
    assert all(math.isfinite(loss) for _, loss, _ in result.history)
    assert all(bool(torch.isfinite(p).all()) for p in result.model.parameters())


def test_a_non_finite_step_is_skipped_and_the_weights_stay_finite(fourier, monkeypatch):
    monkeypatch.setitem(model_registry.MODELS, "nan-once", _NaNOnce)
    result = train(fourier.setup, model="nan-once", data=DATA, max_steps=3, validate_every=3)
    losses = [loss for _, loss, _ in result.history]
    assert math.isnan(losses[0]) and all(math.isfinite(v) for v in losses[1:])
    assert all(bool(torch.isfinite(p).all()) for p in result.model.parameters())
    assert result.header.training["best_validation"] < result.header.training["zero_floor"]


def test_training_gives_unrolled_rl_the_datas_read_noise_unless_the_config_sets_it(fourier):
    noisy = TrainingDataSpec(seed=1, read_noise=1.5)
    result = train(fourier.setup, data=noisy, max_steps=1)
    assert result.header.config["read_noise"] == 1.5
    chosen = train(fourier.setup, data=noisy, max_steps=1, config={"read_noise": 0.5})
    assert chosen.header.config["read_noise"] == 0.5


def test_the_registrys_learned_method_runs_a_checkpoint_and_is_differentiable(tmp_path):
    from lfm_studio.engine.operators import ShiftInvariantProjector
    from lfm_studio.engine.reconstruct import registry

    g = torch.Generator().manual_seed(0)
    projector = ShiftInvariantProjector(torch.rand(2, 12, 12, generator=g, dtype=torch.float64), (6, 6))
    setup = type("Setup", (), {"projector": projector, "volume_shape": projector.volume_shape,
                               "voxel_size": (1e-6, 1e-6, 1e-6)})()  # fmt: skip
    model = _perturbed(setup)
    path = save_checkpoint(
        tmp_path / "m.safetensors", model, header_for("unrolled-rl", model.config, setup, None, (0.0, 1e-6))
    )
    method = registry.get("learned")
    assert "learned" in registry.names() and method.differentiable
    frame = (
        projector.forward(torch.rand(projector.volume_shape, generator=g, dtype=torch.float64)).detach() + 0.5
    )
    with torch.no_grad():
        torch.testing.assert_close(method(projector, frame, {"model": str(path)}), model(frame))
    weights = torch.linspace(0.5, 1.5, 72, dtype=torch.float64).reshape(projector.volume_shape)
    assert torch.autograd.gradcheck(
        lambda y: (method(projector, y, {"model": str(path)}) * weights).sum(), (frame.clone().requires_grad_(True),),
        eps=1e-6, atol=1e-5,
    )  # fmt: skip
    # A frame without signal above its background is RL's refusal, not a complaint about the model.
    for blank, background in ((torch.zeros_like(frame), 0.0), (frame, float(frame.max()) + 1.0)):
        with pytest.raises(ValueError, match="image has no signal above the background"):
            method(projector, blank, {"model": str(path), "background": background})


def test_a_checkpoint_of_an_older_architecture_or_another_config_is_refused_by_name(fourier, tmp_path):
    setup = fourier.setup
    model = build_model("multiwiener", setup.projector, width=8)
    old_config = {k: v for k, v in model.config.items() if k not in ("architecture", "learn_filters")}
    old = save_checkpoint(  # what MultiWienerNet architecture 1 wrote: no "architecture" entry
        tmp_path / "old.safetensors", model, header_for("multiwiener", old_config, setup, None, ())
    )
    with pytest.raises(ValueError, match=r"architecture 1 .*builds architecture 3.*Fix: train it again"):
        load_model(old, setup)
    with pytest.raises(ValueError, match=r"architecture 1 .*builds architecture 3"):
        train(setup, model="multiwiener", data=DATA, max_steps=1, checkpoint=old, resume=True)
    with pytest.raises(ValueError, match="architecture 7 cannot be built"):
        build_model("multiwiener", setup.projector, architecture=7)
    current = save_checkpoint(
        tmp_path / "new.safetensors", model, header_for("multiwiener", model.config, setup, None, ())
    )
    loaded, _ = load_model(current, setup)
    assert loaded.config == model.config
    with pytest.raises(
        ValueError, match=r"--resume: .* with config .*Fix: resume with the same model config"
    ):
        train(setup, model="multiwiener", config={"width": 16}, data=DATA, max_steps=1, checkpoint=current,
              resume=True)  # fmt: skip


def test_multiwiener_architecture_2_still_loads_off_the_lenslet_lattice_only(fourier, conventional, tmp_path):
    # Architecture 3 changed only the conventional stage (normalised adjoint -> lattice Tikhonov).
    for system, loads in ((fourier, True), (conventional, False)):
        setup = system.setup
        model = build_model("multiwiener", setup.projector, width=8, architecture=2) if loads else None
        if model is None:
            with pytest.raises(ValueError, match=r"architecture 2 cannot be built .*builds architecture 3"):
                build_model("multiwiener", setup.projector, width=8, architecture=2)
            model = build_model("multiwiener", setup.projector, width=8)
        config = {**model.config, "architecture": 2}
        path = save_checkpoint(
            tmp_path / f"{loads}.safetensors", model, header_for("multiwiener", config, setup, None, ())
        )
        if loads:
            loaded, _ = load_model(path, setup)
            assert loaded.config["architecture"] == 2
        else:
            with pytest.raises(
                ValueError, match=r"architecture 2 .*builds architecture 3.*Fix: train it again"
            ):
                load_model(path, setup)


def test_a_short_multiwiener_training_is_not_trivial_and_moves_away_from_its_start(fourier):
    setup = fourier.setup
    data = TrainingDataSpec(seed=1, phantoms="beads")
    torch.manual_seed(0)
    start = build_model("multiwiener", setup.projector)
    result = train(setup, model="multiwiener", data=data, max_steps=40, validate_every=10)
    test = make_samples(data, setup, "test", 4)
    norm = adjoint_normaliser(setup.projector)
    with torch.no_grad():
        volumes = [result.model(s.image) for s in test]
        trained = [float(ncc(s.truth, v)) for s, v in zip(test, volumes, strict=True)]
        floor = [float(ncc(s.truth, setup.projector.adjoint(s.image) / norm)) for s in test]
        untrained = [float(ncc(s.truth, start(s.image))) for s in test]
    assert all(trivial_reason(v) is None and float(v.std()) > 0 for v in volumes)
    assert result.header.training["best_validation"] < result.header.training["zero_floor"]
    assert result.header.training["parameters"] <= 200_000
    # Measured: mean NCC 0.34 trained, 0.19 back-projection, 0.08 untrained (4 test phantoms).
    assert sum(trained) - sum(floor) > 0.2 and sum(trained) - sum(untrained) > 0.4, (
        trained,
        floor,
        untrained,
    )


def test_a_short_conventional_multiwiener_training_beats_the_back_projection_floor(conventional):
    # Architecture 3's lattice Tikhonov stage: the normalised adjoint of architecture 2 stayed near
    # this floor on the benchmark's conventional preset (docs/learned.md).
    setup = conventional.setup
    data = TrainingDataSpec(seed=3, phantoms="beads")
    torch.manual_seed(0)
    result = train(setup, model="multiwiener", data=data, max_steps=60, validate_every=20)
    _assert_beats_the_back_projection_floor(setup, result.model, make_samples(data, setup, "test", 4))


def _assert_beats_the_back_projection_floor(setup, model, test, margin: float = 0.1) -> None:
    """``model`` is not trivial and beats ``A^T y / A^T 1`` by ``margin`` NCC on every test sample."""
    norm = adjoint_normaliser(setup.projector)
    with torch.no_grad():
        trained = [float(ncc(s.truth, model(s.image))) for s in test]
        floor = [float(ncc(s.truth, setup.projector.adjoint(s.image) / norm)) for s in test]
        assert all(trivial_reason(model(s.image)) is None for s in test)
    assert min(t - f for t, f in zip(trained, floor, strict=True)) > margin, (trained, floor)


def test_a_learned_volume_is_checked_against_the_frames_photons(fourier):
    # sum(A x) = <x, A^T 1>: the truth predicts the frame's photons; 1000 times it (a model that does
    # not fit the data) warns; an all-zero or non-finite volume is refused, naming the checkpoint.
    import warnings

    from lfm_studio.engine.learned.method import LearnedOutputWarning, check_learned_volume

    projector = fourier.setup.projector
    truth = make_samples(DATA, fourier.setup, "test", 1)[0].truth
    frame = projector.forward(truth)
    sensitivity = adjoint_normaliser(projector)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_learned_volume(truth, frame, sensitivity, "m.safetensors")  # balanced: silent
    with pytest.warns(LearnedOutputWarning, match=r"m.safetensors predicts .* photons .* the frame holds"):
        check_learned_volume(1e3 * truth, frame, sensitivity, "m.safetensors")
    with pytest.warns(LearnedOutputWarning, match="does not fit this data"):
        check_learned_volume(1e-3 * truth, frame, sensitivity, "m.safetensors")
    with pytest.warns(LearnedOutputWarning, match="the frame holds -"):  # a frame without signal: checked too
        check_learned_volume(truth, -frame, sensitivity, "m.safetensors")
    for bad in (torch.zeros_like(truth), truth * float("nan")):
        with pytest.raises(ValueError, match=r"m.safetensors returned a volume that is .*Fix:"):
            check_learned_volume(bad, frame, sensitivity, "m.safetensors")


def test_a_budget_run_reports_progress_in_seconds_of_its_budget(fourier):
    """Without a step cap the progress total is the budget in seconds and ``done`` the seconds spent
    (it used to report a total of 0, which a progress bar cannot show)."""
    ticks = iter(range(0, 10_000, 7))  # each clock() call advances 7 s
    calls = []
    result = train(
        fourier.setup,
        data=DATA,
        budget_minutes=1.0,
        validate_every=100,
        clock=lambda: float(next(ticks)),
        progress=lambda done, total, message: calls.append((done, total, message)),
    )
    assert result.stop_reason == "time budget"
    assert calls and {total for _, total, _ in calls} == {60}
    done = [d for d, _, _ in calls]
    assert done == sorted(done) and done[0] > 0 and done[-1] <= 60
    assert calls[0][2].startswith("step 1:")
