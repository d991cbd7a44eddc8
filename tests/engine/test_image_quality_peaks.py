"""NCC against numpy's corrcoef; peak detection and matching on constructed volumes."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from lfm_studio.engine.image_quality import find_peaks, looks_point_like, match_peaks, ncc, peak_match
from lfm_studio.engine.image_quality.peaks import _box_max

# ----- NCC -----


@pytest.mark.parametrize("shape", [(50,), (20, 30), (4, 9, 11)])
def test_ncc_matches_numpy_corrcoef(shape):
    rng = np.random.default_rng(7)
    truth = rng.random(shape)
    estimate = 0.6 * truth + rng.random(shape)
    reference = np.corrcoef(truth.ravel(), estimate.ravel())[0, 1]
    # Two float64 code paths over <= 550 values: agreement to 1e-12.
    assert float(ncc(truth, estimate)) == pytest.approx(reference, abs=1e-12)
    assert float(ncc(torch.from_numpy(truth).float(), torch.from_numpy(estimate).float())) == pytest.approx(
        reference, abs=1e-6
    )


def test_ncc_ignores_scale_and_offset_and_scores_structureless_volumes_zero():
    rng = np.random.default_rng(3)
    truth = rng.random((5, 16, 16))
    assert float(ncc(truth, 3.0 * truth + 10.0)) == pytest.approx(1.0, abs=1e-12)
    assert float(ncc(truth, -truth)) == pytest.approx(-1.0, abs=1e-12)
    assert float(ncc(truth, np.zeros_like(truth))) == 0.0
    assert float(ncc(truth, np.full_like(truth, 4.0))) == 0.0
    assert float(ncc(np.zeros_like(truth), truth)) == 0.0
    shuffled = rng.permutation(truth.ravel()).reshape(truth.shape)
    assert abs(float(ncc(truth, shuffled))) < 0.1  # 1280 voxels: |r| ~ 1/sqrt(N) = 0.03


def test_ncc_is_differentiable_and_checks_shapes():
    truth = torch.rand(3, 8, 8, dtype=torch.float64)
    estimate = torch.rand(3, 8, 8, dtype=torch.float64, requires_grad=True)
    ncc(truth, estimate).backward()
    assert estimate.grad is not None and torch.isfinite(estimate.grad).all()
    with pytest.raises(ValueError, match="shape"):
        ncc(truth, torch.rand(3, 8, 9))


# ----- peak detection -----


def _blobs(shape, centres, heights, sigma=0.8) -> torch.Tensor:
    z, y, x = torch.meshgrid(*(torch.arange(n, dtype=torch.float64) for n in shape), indexing="ij")
    volume = torch.zeros(shape, dtype=torch.float64)
    for (cz, cy, cx), h in zip(centres, heights, strict=True):
        volume += h * torch.exp(-((z - cz) ** 2 + (y - cy) ** 2 + (x - cx) ** 2) / (2 * sigma**2))
    return volume


@pytest.mark.parametrize(("shape", "r"), [((5, 7, 9), 1), ((4, 30, 31), 2), ((1, 6, 6), 1)])
def test_separable_box_maximum_equals_max_pool3d(shape, r):
    x = torch.randn(shape, generator=torch.Generator().manual_seed(r), dtype=torch.float64)
    reference = torch.nn.functional.max_pool3d(x[None, None], 2 * r + 1, stride=1, padding=r)[0, 0]
    assert torch.equal(_box_max(x, r), reference)  # maxima of the same values: exact


def test_find_peaks_returns_the_constructed_maxima_brightest_first():
    centres = [(2, 5, 5), (4, 20, 12), (1, 14, 25), (5, 25, 4)]
    heights = [3.0, 5.0, 1.0, 0.05]  # the last is below 10 % of the maximum
    peaks = find_peaks(_blobs((7, 30, 30), centres, heights))
    assert peaks.positions.tolist() == [[4, 20, 12], [2, 5, 5], [1, 14, 25]]
    assert peaks.values.tolist() == pytest.approx([5.0, 3.0, 1.0], rel=1e-3)
    assert len(find_peaks(_blobs((7, 30, 30), centres, heights), threshold=0.0)) == 4


def test_find_peaks_flat_and_empty_volumes_have_none_and_plateaus_give_one():
    assert len(find_peaks(torch.zeros(3, 10, 10))) == 0
    assert len(find_peaks(torch.full((3, 10, 10), 2.0))) == 0
    assert len(find_peaks(-torch.rand(3, 10, 10) - 0.1)) == 0
    plateau = torch.zeros(3, 10, 10)
    plateau[1, 4, 4] = plateau[1, 4, 5] = 1.0  # two equal neighbours: one peak (first in C order)
    plateau[1, 8, 1] = 0.5
    peaks = find_peaks(plateau)
    assert peaks.positions.tolist() == [[1, 4, 4], [1, 8, 1]]


def test_find_peaks_min_distance_suppresses_the_weaker_neighbour():
    volume = torch.zeros(1, 12, 12)
    volume[0, 5, 5], volume[0, 5, 7] = 1.0, 0.8  # 2 voxels apart
    assert len(find_peaks(volume, min_distance=1)) == 2
    assert find_peaks(volume, min_distance=2).positions.tolist() == [[0, 5, 5]]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"threshold": 1.0}, "threshold"),
        ({"threshold": -0.1}, "threshold"),
        ({"min_distance": 0}, "min_distance"),
    ],
)
def test_find_peaks_bad_settings_are_named(kwargs, message):
    with pytest.raises(ValueError, match=message):
        find_peaks(torch.rand(3, 5, 5), **kwargs)
    with pytest.raises(ValueError, match="volume"):
        find_peaks(torch.rand(5, 5))


def test_looks_point_like():
    points = torch.zeros(5, 20, 20)
    points[1, 3, 4] = points[3, 15, 12] = 1.0
    assert looks_point_like(points)
    z, y, x = torch.meshgrid(torch.arange(5), torch.arange(20), torch.arange(20), indexing="ij")
    sphere = (((z - 2) ** 2 + (y - 10) ** 2 + (x - 10) ** 2) <= 9).double() * (1 + 0.01 * y)
    assert not looks_point_like(sphere)
    assert not looks_point_like(torch.zeros(5, 20, 20))


# ----- matching -----

TRUTH = torch.tensor([[1.0, 5.0, 5.0], [2.0, 15.0, 10.0], [3.0, 8.0, 20.0], [4.0, 20.0, 3.0]])


def test_shifted_peaks_within_tolerance_match_and_outside_do_not():
    found = TRUTH + torch.tensor([[0.0, 1.0, 0.0], [0.0, 0.0, 2.0], [0.0, 3.0, 0.0], [0.0, 0.0, 0.0]])
    m = match_peaks(found, TRUTH, tolerance=2.0)
    assert (m.found, m.reference, m.matched) == (4, 4, 3)  # the 3-voxel shift is out
    assert m.precision == m.recall == 0.75 and m.f1 == pytest.approx(0.75)
    assert m.unit == "voxels" and sorted(m.errors.tolist()) == pytest.approx([0.0, 1.0, 2.0])
    assert m.mean_error == pytest.approx(1.0) and m.rms_error == pytest.approx(math.sqrt(5 / 3))
    assert match_peaks(found, TRUTH, tolerance=3.0).f1 == 1.0


def test_extra_false_peaks_lower_precision_and_missing_peaks_lower_recall():
    extra = torch.cat([TRUTH, torch.tensor([[0.0, 25.0, 25.0], [4.0, 0.0, 0.0]])])
    m = match_peaks(extra, TRUTH)
    assert (m.matched, m.precision, m.recall) == (4, 4 / 6, 1.0)
    assert m.f1 == pytest.approx(2 * 4 / (2 * 4 + 2))
    m = match_peaks(TRUTH[:2], TRUTH)
    assert (m.matched, m.precision, m.recall) == (2, 1.0, 0.5) and m.f1 == pytest.approx(2 / 3)
    assert (
        m.describe("beads") == "2/4 beads" and match_peaks(extra, TRUTH).describe() == "4/4 objects, 2 false"
    )


def test_matching_is_one_to_one_and_takes_the_closest_pair_first():
    reference = torch.tensor([[0.0, 10.0, 10.0]])
    found = torch.tensor([[0.0, 10.0, 11.0], [0.0, 10.0, 10.0]])  # two candidates for one bead
    m = match_peaks(found, reference)
    assert m.matched == 1 and m.pairs.tolist() == [[1, 0]] and m.precision == 0.5


def test_empty_estimate_scores_zero_and_empty_truth_is_handled():
    none = torch.zeros((0, 3))
    m = match_peaks(none, TRUTH)
    assert (m.f1, m.precision, m.recall) == (0.0, 0.0, 0.0) and math.isnan(m.mean_error)
    assert m.to_dict()["mean_error_voxels"] is None
    assert match_peaks(none, none).f1 == 1.0  # nothing there, nothing found
    m = match_peaks(TRUTH, none)
    assert (m.f1, m.precision, m.recall) == (0.0, 0.0, 0.0)


def test_tolerance_and_errors_in_micrometres_with_anisotropic_voxels():
    voxel = (10e-6, 0.5e-6, 0.5e-6)  # dz 10 um, dy = dx = 0.5 um
    reference = torch.tensor([[2.0, 10.0, 10.0], [5.0, 30.0, 30.0]])
    found = torch.tensor([[2.0, 10.0, 12.0], [6.0, 30.0, 30.0]])  # 1 um laterally; 10 um axially
    m = match_peaks(found, reference, tolerance_um=2.0, voxel_size=voxel)
    assert m.matched == 1 and m.errors.tolist() == pytest.approx([1.0]) and m.unit == "um"
    assert m.to_dict()["tolerance_um"] == 2.0 and m.to_dict()["mean_error_um"] == pytest.approx(1.0)
    m = match_peaks(found, reference, tolerance=2.0, voxel_size=voxel)  # in voxels: both pairs match
    assert m.matched == 2 and sorted(m.errors.tolist()) == pytest.approx([1.0, 10.0])
    with pytest.raises(ValueError, match="voxel_size"):
        match_peaks(found, reference, tolerance_um=2.0)
    with pytest.raises(ValueError, match="tolerance"):
        match_peaks(found, reference, tolerance=0.0)


def test_peak_match_of_volumes_uses_the_truth_maxima_or_given_positions():
    truth = torch.zeros(5, 24, 24)
    for z, y, x in TRUTH.long().tolist():
        truth[z, y, x] = 1.0
    estimate = _blobs((5, 24, 24), (TRUTH + torch.tensor([0.0, 1.0, 0.0])).tolist(), [1.0, 0.7, 0.9, 0.4])
    m = peak_match(truth, estimate, tolerance=1.5)
    assert (m.found, m.reference, m.matched) == (4, 4, 4) and m.errors.tolist() == pytest.approx([1.0] * 4)
    m = peak_match(truth, estimate, reference=TRUTH[:2] + torch.tensor([0.0, 1.0, 0.0]))
    assert (m.found, m.reference, m.matched) == (4, 2, 2) and m.mean_error == pytest.approx(0.0)
