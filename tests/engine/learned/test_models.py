"""The three learned models against independent references: plain RL, the engine's Wiener filter, scale."""

from __future__ import annotations

import numpy
import pytest
import torch

from lfm_studio.engine.learned.data import TrainingDataSpec, make_sample
from lfm_studio.engine.learned.losses import training_loss
from lfm_studio.engine.learned.models import MODELS, build_model, parameter_count
from lfm_studio.engine.reconstruct.tikhonov import tikhonov
from lfm_studio.engine.reconstruct.unrolled import richardson_lucy_unrolled
from lfm_studio.engine.reconstruct.wiener import wiener


def _plain_rl(projector, image, iterations):
    """Plain Richardson-Lucy from a flat start, written out here as the reference."""
    y = image.clamp_min(0.0)
    norm = projector.adjoint(torch.ones_like(y))
    norm = norm.clamp_min(float(norm.max()) * 1e-6)
    x = torch.full_like(norm, float(y.sum() / norm.sum()))
    for _ in range(iterations):
        x = x * projector.adjoint(y / projector.forward(x).clamp_min(torch.finfo(y.dtype).eps)) / norm
    return x


@pytest.fixture(scope="module")
def sample(fourier):
    return make_sample(TrainingDataSpec(seed=2, photons=(1e5,)), fourier.setup, "test", 0)


@pytest.mark.parametrize("system", ["fourier", "conventional"])
def test_an_untrained_unrolled_rl_is_plain_rl(system, request):
    setup = request.getfixturevalue(system).setup64  # float64: the two paths differ only by rounding
    image = make_sample(TrainingDataSpec(seed=1, photons=(1e5,)), setup, "test", 1).image.double()
    model = build_model("unrolled-rl", setup.projector, iterations=4)
    # rtol 1e-8: rounding after 4 iterations reached 1.03e-9 relative in one voxel of the conventional
    # system (FFT-built patterns; the largest absolute difference is 1e-10 of the volume's maximum).
    with torch.no_grad():
        torch.testing.assert_close(model(image), _plain_rl(setup.projector, image, 4), rtol=1e-8, atol=1e-9)
        plain = richardson_lucy_unrolled(setup.projector, image.clamp_min(0.0), 4)  # the engine's unrolled RL
        torch.testing.assert_close(model(image), plain, rtol=1e-8, atol=1e-9)


def test_an_untrained_unrolled_rl_with_read_noise_is_rl_on_the_shifted_poisson_data(fourier):
    # Snyder's shifted Poisson: y + sigma^2 against A x + sigma^2. Reference: the engine's production
    # RL on max(y, -sigma^2) + sigma^2 with background sigma^2 (its start is sum(y - b) / sum(A^T 1)).
    from lfm_studio.engine.reconstruct.richardson_lucy import richardson_lucy

    setup, sigma = fourier.setup64, 1.5
    image = make_sample(
        TrainingDataSpec(seed=1, photons=(1e4,), read_noise=sigma), setup, "test", 1
    ).image.double()
    assert float(image.min()) < 0  # the read noise makes pixels negative: the shift matters
    model = build_model("unrolled-rl", setup.projector, iterations=4, read_noise=sigma)
    assert model.config["read_noise"] == sigma
    shifted = image.clamp_min(-(sigma**2)) + sigma**2
    reference = richardson_lucy(setup.projector, shifted, iterations=4, background=sigma**2)
    with torch.no_grad():
        torch.testing.assert_close(model(image), reference, rtol=1e-6, atol=1e-9 * float(reference.max()))
    assert "read_noise" not in build_model("unrolled-rl", setup.projector).config  # older checkpoints: 0
    with pytest.raises(ValueError, match="read_noise must be >= 0"):
        build_model("unrolled-rl", setup.projector, read_noise=-1.0)


def test_an_untrained_multiwiener_stage_is_the_engines_wiener_filter(fourier):
    setup = fourier.setup64
    image = make_sample(TrainingDataSpec(seed=1, photons=(1e5,)), setup, "test", 2).image.double()
    model = build_model("multiwiener", setup.projector, snr=30.0)
    with torch.no_grad():
        stage = model._wiener(image)
    reference = wiener(setup.projector, image, snr=30.0)
    torch.testing.assert_close(stage, reference, rtol=1e-6, atol=1e-7 * float(reference.abs().max()))


def test_an_untrained_conventional_multiwiener_stage_is_the_engines_lattice_tikhonov(conventional):
    setup = conventional.setup64
    image = make_sample(TrainingDataSpec(seed=1, photons=(1e5,)), setup, "test", 2).image.double()
    model = build_model("multiwiener", setup.projector)
    assert model.config["snr"] == 1000.0  # the registry's Tikhonov default on this kind
    with torch.no_grad():
        stage = model.lattice(image / image.mean())
    reference = tikhonov(setup.projector, image, mu=1e-3) / image.mean()
    torch.testing.assert_close(stage, reference, rtol=1e-9, atol=1e-9 * float(reference.abs().max()))
    assert build_model("multiwiener", setup.projector, snr=50.0).lattice.mu == pytest.approx(0.02)


@pytest.mark.parametrize(
    ("name", "config"), [(name, {}) for name in sorted(MODELS)] + [("multiwiener", {"learn_filters": True})]
)
@pytest.mark.parametrize("system", ["fourier", "conventional"])
def test_every_model_maps_an_image_to_a_non_negative_volume_and_learns_through_every_parameter(
    name, config, system, request
):
    setup = request.getfixturevalue(system).setup
    sample = make_sample(TrainingDataSpec(seed=5, photons=(1e5,)), setup, "train", 0)
    torch.manual_seed(0)
    if config.get("learn_filters") and system == "conventional":
        with pytest.raises(
            ValueError, match=r"learn_filters=True needs a shift-invariant .*Fix: leave learn_filters"
        ):
            build_model(name, setup.projector, **config)
        return
    model = build_model(name, setup.projector, **config)
    assert parameter_count(model) <= 200_000
    volume = model(sample.image)
    assert volume.shape == tuple(setup.volume_shape) and float(volume.detach().min()) >= 0
    training_loss(volume, sample.truth).backward()
    trained = [(n, p) for n, p in model.named_parameters() if p.requires_grad]
    missing = [n for n, p in trained if p.grad is None or not bool(p.grad.abs().sum() > 0)]
    if name == "multiwiener" and system == "fourier":  # frozen filters get no gradient; learned ones do
        frozen = {n for n, p in model.named_parameters() if not p.requires_grad}
        assert frozen == (set() if config.get("learn_filters") else {"log_snr", "radial_gain"})
    # Unrolled RL's first layers see a zero gradient until the zero-initialised last layers move.
    if name == "unrolled-rl":
        missing = [n for n in missing if not n.endswith(("inner.weight", "inner.bias"))]
    assert missing == []


@pytest.mark.parametrize("name", ["unrolled-rl", "multiwiener", "unet"])
def test_models_answer_in_proportion_to_the_photon_count(fourier, sample, name):
    torch.manual_seed(0)
    model = build_model(name, fourier.setup.projector)
    with torch.no_grad():
        one, ten = model(sample.image), model(10.0 * sample.image)
    torch.testing.assert_close(ten, 10.0 * one, rtol=1e-4, atol=1e-4 * float(ten.abs().max()))


def test_the_models_at_the_issues_size_stay_within_200k_parameters():
    """512^2 x 32 depths needs no PSF: parameter counts depend only on the depth count and config."""
    from lfm_studio.engine.learned.models.common import SmallUNet

    unet = sum(p.numel() for p in SmallUNet(32, 32, 16).parameters())
    assert unet + 1 <= 200_000  # multiwiener's default: U-Net + output gain (frozen filters)
    assert unet + 1 + 32 + 32 * 8 <= 200_000  # learn_filters=True


def test_unknown_model_is_named():
    with pytest.raises(ValueError, match="model must be one of"):
        build_model("vcd-net", None)


class _Unpruned:
    """A Fourier projector without the pruned ``filtered_adjoint``: the stage takes the full-size path."""

    def __init__(self, projector) -> None:
        self._p = projector
        for name in ("volume_shape", "image_shape", "device", "dtype", "otf", "fft_shape", "full_shape"):
            setattr(self, name, getattr(projector, name))
        self.forward, self.adjoint, self.depth_chunks = (
            projector.forward,
            projector.adjoint,
            projector.depth_chunks,
        )


def test_the_pruned_wiener_stage_equals_the_full_size_transforms_with_trained_filters(fourier):
    from lfm_studio.engine.learned.models.wiener_stage import WienerGeometry
    from lfm_studio.engine.operators import FourierProjector, PrunedFourierProjector

    projector = fourier.setup64.projector
    unpruned = _Unpruned(projector)
    assert isinstance(unpruned, FourierProjector) and not isinstance(unpruned, PrunedFourierProjector)
    image = make_sample(TrainingDataSpec(seed=1, photons=(1e5,)), fourier.setup64, "test", 3).image.double()
    generator = torch.Generator().manual_seed(4)
    depths = projector.volume_shape[0]
    log_snr = torch.log(torch.tensor(30.0)) + torch.randn(depths, generator=generator, dtype=torch.float64)
    gain = 1.0 + 0.5 * torch.randn(depths, 8, generator=generator, dtype=torch.float64)
    volumes = []
    for geometry in (WienerGeometry(projector, 8), WienerGeometry(unpruned, 8)):
        volumes.append(geometry.apply(image, geometry.filters(log_snr, gain)))
    assert WienerGeometry(projector, 8).pruned and not WienerGeometry(unpruned, 8).pruned
    torch.testing.assert_close(volumes[0], volumes[1], rtol=1e-9, atol=1e-9 * float(volumes[1].abs().max()))


def test_the_radial_gain_interpolates_linearly_between_its_control_points(fourier):
    from lfm_studio.engine.learned.models.wiener_stage import WienerGeometry
    from lfm_studio.engine.reconstruct.fourier_geometry import radial_frequency

    projector = fourier.setup64.projector
    geometry = WienerGeometry(projector, 4)
    gain = torch.tensor([[1.0, 3.0, 2.0, 0.0]], dtype=torch.float64)
    radial = (gain @ geometry.basis).reshape(geometry.power.shape[1:])
    position = (radial_frequency(projector) / radial_frequency(projector).max() * 3).T  # pruned layout
    expected = torch.from_numpy(numpy.interp(position.numpy(), [0, 1, 2, 3], gain[0].numpy()))
    torch.testing.assert_close(radial, expected)
    with pytest.raises(ValueError, match="bins must be an integer >= 2"):
        build_model("multiwiener", projector, bins=1)


def test_trained_multiwiener_filters_are_kept_until_a_parameter_changes(fourier, sample):
    torch.manual_seed(0)
    model = build_model("multiwiener", fourier.setup.projector).eval()
    with torch.no_grad():
        first = model(sample.image)
        kept = model._cached[1]
        assert torch.equal(model(sample.image), first) and model._cached[1] is kept
        model.log_snr.add_(1.0)  # an in-place change (an optimiser step, load_state_dict)
        changed = model(sample.image)
    assert model._cached[1] is not kept and not torch.equal(changed, first)
    assert torch.equal(changed, model(sample.image).detach())  # with autograd: built afresh, same values
