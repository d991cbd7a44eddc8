"""Optics-mismatch augmentation: jittered designs, images through them, the option in training."""

from __future__ import annotations

import warnings

import pytest
import torch

from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.learned.checkpoint import read_checkpoint
from lfm_studio.engine.learned.data import TrainingDataSpec, make_sample
from lfm_studio.engine.learned.mismatch import (
    jitter_paths,
    jitter_space,
    jittered_designs,
    mismatch_pool,
    resample_to_grid,
)
from lfm_studio.engine.learned.train import train
from tests.engine.reconstruct.conftest import _shrink


@pytest.fixture(scope="module")
def pool_of(fourier):
    pools: dict[float, object] = {}

    def get(fraction: float):
        if fraction not in pools:
            pools[fraction] = mismatch_pool(fourier.design, fraction, count=2, seed=5)
        return pools[fraction]

    return get


def _conventional_design():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        return _shrink("lfm_10x_na03", 130, (-20.0, 20.0), 20.0)


@pytest.mark.parametrize("kind", ["fourier", "conventional"])
def test_jittered_designs_stay_within_the_fraction_and_are_seeded(kind, fourier):
    design = fourier.design if kind == "fourier" else _conventional_design()
    paths = jitter_paths(design)
    expected = {"mla focal length", "numerical aperture", "wavelength"}
    assert set(paths) == (expected | {"fourier lens focal length"} if kind == "fourier" else expected)
    fraction = 0.03
    space = jitter_space(design, fraction)
    nominal = space.values_of(design)
    designs = jittered_designs(design, fraction, count=6, seed=2)
    assert len(designs) == 6
    moved = set()
    for jittered in designs:
        for quantity, group in paths.items():
            values = space.values_of(jittered)
            ratios = [values[p] / nominal[p] for p in group]
            assert all(space.parameters[space.names.index(p)].low <= values[p] for p in group)
            assert all(abs(r - 1.0) <= fraction + 1e-12 for r in ratios), (quantity, ratios)
            assert max(ratios) - min(ratios) < 1e-12  # one factor per quantity (the whole MLA scales)
            if abs(ratios[0] - 1.0) > 1e-6:
                moved.add(quantity)
        # nothing else changes (the camera, depths, MLA layout, distances)
        assert jittered.camera == design.camera and jittered.depths == design.depths
        assert jittered.mla_to_camera_distance_mm == design.mla_to_camera_distance_mm
    assert moved == set(paths)
    again = jittered_designs(design, fraction, count=6, seed=2)
    assert [d.model_dump() for d in again] == [d.model_dump() for d in designs]
    other = jittered_designs(design, fraction, count=6, seed=3)
    assert [d.model_dump() for d in other] != [d.model_dump() for d in designs]
    assert all(d.model_dump() == design.model_dump() for d in jittered_designs(design, 0.0, count=2))


def test_the_jitter_is_refused_out_of_range():
    for bad in (-0.01, 0.5, float("nan")):
        with pytest.raises(ValueError, match=r"optics_jitter must be a relative jitter between 0 and 0\.2"):
            TrainingDataSpec(optics_jitter=bad)
    with pytest.raises(ValueError, match=r"jitter_designs must be an integer >= 1"):
        TrainingDataSpec(optics_jitter=0.03, jitter_designs=0)


def test_resampling_keeps_physical_positions():
    volume = torch.zeros(2, 21, 21)
    volume[1, 10, 14] = 1.0  # 4 voxels right of the axis: 4 um at 1 um voxels
    out = resample_to_grid(volume, (1.0, 1.0, 1.0), (2, 41, 41), (1.0, 0.5, 0.5))
    assert out.shape == (2, 41, 41) and float(out[0].abs().sum()) == 0.0
    assert torch.nonzero(out[1] == out[1].max()).tolist() == [[20, 28]]  # 8 half-voxels right
    assert resample_to_grid(volume, (1.0, 1.0, 1.0), (2, 21, 21), (1.0, 1.0, 1.0)) is volume


def test_resampling_conserves_photons():
    """Photons per voxel: a grid of 3 % larger (smaller) voxels holds the same light in fewer
    (more) voxels, so each voxel gets the area ratio more; a smooth blob's total is kept to the
    bilinear interpolation error (< 1 % here; before the area factor it was off by 1/r^2, about 6 %)."""
    y, x = torch.meshgrid(torch.arange(41.0) - 20, torch.arange(41.0) - 20, indexing="ij")
    blob = torch.exp(-(x**2 + y**2) / (2 * 4.0**2))
    volume = torch.stack([blob, 2 * blob])
    for ratio in (0.97, 1.03):
        out = resample_to_grid(volume, (1.0, 1.0, 1.0), (2, 41, 41), (1.0, ratio, ratio))
        for z in range(2):
            assert float(out[z].sum()) == pytest.approx(float(volume[z].sum()), rel=1e-2)


def test_jittered_images_differ_from_the_nominal_ones_and_equal_them_without_jitter(fourier, pool_of):
    spec = TrainingDataSpec(seed=1)
    for index in range(3):
        nominal = make_sample(spec, fourier.setup, "train", index)
        same = make_sample(spec, fourier.setup, "train", index, imaging=pool_of(0.0))
        assert torch.equal(same.image, nominal.image) and torch.equal(same.truth, nominal.truth)
        jittered = make_sample(spec, fourier.setup, "train", index, imaging=pool_of(0.05))
        assert jittered.seed == nominal.seed and jittered.phantom == nominal.phantom
        assert jittered.truth.shape == nominal.truth.shape and jittered.image.shape == nominal.image.shape
        assert float((jittered.image - nominal.image).abs().mean()) > 0.01 * float(nominal.image.abs().mean())
        # the same phantom (up to the photon scale): the truth is on the nominal grid
        assert torch.allclose(jittered.truth / jittered.truth.sum(), nominal.truth / nominal.truth.sum())


def test_training_with_jitter_records_it_and_needs_the_design(fourier, tmp_path):
    spec = TrainingDataSpec(seed=1, optics_jitter=0.03, jitter_designs=2)
    with pytest.raises(ValueError, match=r"optics_jitter 0.03 \(--optics-jitter\) needs the design.*Fix:"):
        train(fourier.setup, data=spec, max_steps=1)
    path = tmp_path / "m.safetensors"
    result = train(
        fourier.setup, data=spec, design=fourier.design, max_steps=2, validate_every=2, checkpoint=path
    )
    header, _ = read_checkpoint(path)
    assert header.data["optics_jitter"] == 0.03 and header.data["jitter_designs"] == 2
    assert header.data["jitter_validation"] is False
    assert TrainingDataSpec.from_dict(header.data) == spec == TrainingDataSpec.from_dict(result.header.data)
