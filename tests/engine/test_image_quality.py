"""Reference metrics: MSE/PSNR/SSIM against scikit-image (or the paper's formulas), curves, LPIPS message."""

from __future__ import annotations

import json
import math
import textwrap

import numpy as np
import pytest
import torch

from lfm_studio.engine.image_quality import (
    LPIPSUnavailableError,
    compare,
    depth_curves,
    gaussian_filter,
    lpips,
    lpips_available,
    match_scale,
    mse,
    perceptual,
    psnr,
    ssim,
)

try:  # scikit-image is the reference where installed; else the paper's formulas written here
    from skimage.metrics import structural_similarity as _skimage_ssim
except ImportError:  # pragma: no cover - depends on the environment
    _skimage_ssim = None


def _paper_ssim(a: np.ndarray, b: np.ndarray, data_range: float, sigma: float = 1.5) -> float:
    """Wang et al. 2004 with an 11-tap Gaussian (truncate 3.5 sigma), half-sample reflect edges,
    population covariances, mean after cropping the window radius: written independently in numpy."""
    radius = int(3.5 * sigma + 0.5)
    x = np.arange(-radius, radius + 1)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    w /= w.sum()

    def smooth(img: np.ndarray) -> np.ndarray:
        for axis in range(img.ndim):
            padded = np.pad(
                img, [(radius, radius) if k == axis else (0, 0) for k in range(img.ndim)], "symmetric"
            )
            img = sum(
                w[k] * np.take(padded, np.arange(k, k + img.shape[axis]), axis=axis) for k in range(len(w))
            )
        return img

    c1, c2 = (0.01 * data_range) ** 2, (0.03 * data_range) ** 2
    ma, mb = smooth(a), smooth(b)
    va, vb, cab = smooth(a * a) - ma**2, smooth(b * b) - mb**2, smooth(a * b) - ma * mb
    s = (2 * ma * mb + c1) * (2 * cab + c2) / ((ma**2 + mb**2 + c1) * (va + vb + c2))
    return float(s[tuple(slice(radius, n - radius) for n in s.shape)].mean())


def _reference_ssim(a: np.ndarray, b: np.ndarray, data_range: float) -> float:
    if _skimage_ssim is not None:
        return float(
            _skimage_ssim(
                a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=data_range
            )
        )
    return _paper_ssim(a, b, data_range)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


def _smooth_pair(rng, shape, noise):
    truth = gaussian_filter(torch.from_numpy(rng.random(shape)), 2.0).numpy() * 50.0 + 3.0
    return truth, truth + noise * rng.standard_normal(shape)


@pytest.mark.parametrize("shape", [(40, 52), (11, 11), (12, 24, 20)])
def test_ssim_matches_reference_2d_and_3d(rng, shape):
    # Tolerance 1e-9: both sides compute in float64 the same sums (11 taps per axis);
    # measured difference is below 1e-15.
    truth, estimate = _smooth_pair(rng, shape, noise=1.5)
    r = float(truth.max() - truth.min())
    assert float(ssim(truth, estimate, data_range=r)) == pytest.approx(
        _reference_ssim(truth, estimate, r), abs=1e-9
    )
    # The default data range is the truth's max - min.
    assert float(ssim(truth, estimate)) == pytest.approx(
        float(ssim(truth, estimate, data_range=r)), abs=1e-15
    )


@pytest.mark.parametrize("value", [0.0, 7.5])
def test_ssim_of_a_constant_estimate_matches_the_reference(rng, value):
    # A constant estimate (the all-zero and constant floors) takes a shorter path in ssim_map.
    truth, _ = _smooth_pair(rng, (12, 24, 20), noise=0.0)
    constant = np.full_like(truth, value)
    r = float(truth.max() - truth.min())
    assert float(ssim(truth, constant, data_range=r)) == pytest.approx(
        _reference_ssim(truth, constant, r), abs=1e-9
    )


def test_paper_formula_agrees_with_skimage_so_the_fallback_reference_is_valid(rng):
    if _skimage_ssim is None:
        pytest.skip("scikit-image not installed")
    truth, estimate = _smooth_pair(rng, (30, 33), noise=2.0)
    assert _paper_ssim(truth, estimate, 40.0) == pytest.approx(
        _reference_ssim(truth, estimate, 40.0), abs=1e-12
    )


def test_gaussian_filter_matches_scipy(rng):
    ndimage = pytest.importorskip("scipy.ndimage")
    x = rng.random((9, 14, 17))
    ours = gaussian_filter(torch.from_numpy(x), (0.8, 1.5, 2.5)).numpy()
    ref = ndimage.gaussian_filter(x, (0.8, 1.5, 2.5), mode="reflect", truncate=3.5)
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-12)  # float64 sums of <= 19 taps


def test_ssim_identity_is_one_and_orders_noise_levels(rng):
    truth, _ = _smooth_pair(rng, (8, 32, 32), noise=0.0)
    t = torch.from_numpy(truth)
    assert float(ssim(t, t, sigma=(0, 1.5, 1.5))) == pytest.approx(1.0, abs=1e-12)
    noise = torch.from_numpy(rng.standard_normal(truth.shape))
    scores = [float(ssim(t, t + level * noise, sigma=(0, 1.5, 1.5))) for level in (0.1, 1.0, 5.0, 20.0)]
    assert scores == sorted(scores, reverse=True) and scores[0] > 0.95 and scores[-1] < 0.5
    psnrs = [float(psnr(t, t + level * noise)) for level in (0.1, 1.0, 5.0, 20.0)]
    assert psnrs == sorted(psnrs, reverse=True)


def test_ssim_window_larger_than_axis_is_a_named_error(rng):
    truth, estimate = _smooth_pair(rng, (5, 32, 32), noise=1.0)
    with pytest.raises(ValueError, match=r"axis Z has 5 samples.*11-sample.*sigma=\(0, 1.5, 1.5\)"):
        ssim(truth, estimate)
    # With no smoothing across z the 3D SSIM is the mean of the per-slice 2D SSIMs.
    per_slice = [
        float(ssim(t, e, data_range=float(np.ptp(truth)))) for t, e in zip(truth, estimate, strict=True)
    ]
    assert float(ssim(truth, estimate, sigma=(0, 1.5, 1.5))) == pytest.approx(np.mean(per_slice), abs=1e-12)


def test_mse_and_psnr_with_explicit_range():
    truth = torch.zeros(4, 4, dtype=torch.float64)
    truth[0, 0] = 2.0  # range 2
    estimate = truth + 0.5  # MSE 0.25 exactly
    assert float(mse(truth, estimate)) == 0.25
    # PSNR = 10 log10(R^2 / MSE): default R = 2 -> 10 log10(16); R = 255 is the 8-bit convention of eq. 2.3.
    assert float(psnr(truth, estimate)) == pytest.approx(10 * math.log10(16.0), abs=1e-12)
    assert float(psnr(truth, estimate, data_range=255)) == pytest.approx(
        10 * math.log10(255**2 / 0.25), abs=1e-12
    )
    assert math.isinf(float(psnr(truth, truth)))
    skimage = pytest.importorskip("skimage.metrics")
    rng = np.random.default_rng(0)
    a, b = rng.random((20, 20)), rng.random((20, 20))
    assert float(psnr(a, b, data_range=3.0)) == pytest.approx(
        skimage.peak_signal_noise_ratio(a, b, data_range=3.0), abs=1e-10
    )


def test_psnr_input_errors_are_named():
    with pytest.raises(ValueError, match=r"truth is constant.*pass data_range"):
        psnr(torch.ones(3, 3), torch.zeros(3, 3))
    with pytest.raises(ValueError, match=r"truth has shape \(3, 3\) but estimate has shape \(3, 4\)"):
        psnr(torch.rand(3, 3), torch.rand(3, 4))
    with pytest.raises(ValueError, match="NaN/Inf"):
        psnr(torch.rand(3, 3), torch.full((3, 3), float("nan")))
    with pytest.raises(ValueError, match="data_range must be"):
        psnr(torch.rand(3, 3), torch.rand(3, 3), data_range=-1.0)


def test_metrics_are_differentiable_in_the_estimate(rng):
    truth = torch.from_numpy(_smooth_pair(rng, (16, 16), 0.0)[0])
    estimate = (truth + 0.3).requires_grad_(True)
    (-ssim(truth, estimate) - psnr(truth, estimate)).backward()
    assert estimate.grad is not None and torch.isfinite(estimate.grad).all() and estimate.grad.abs().sum() > 0


def test_match_scale_modes():
    truth = torch.tensor([1.0, 2.0, 3.0, 4.0], dtype=torch.float64)
    assert torch.allclose(
        match_scale(truth * 0.01, truth, "scale"), truth
    )  # least squares: exact for a multiple
    assert torch.allclose(match_scale(truth * 3 + 7, truth, "affine"), truth)
    assert float(match_scale(truth * 5, truth, "sum").sum()) == pytest.approx(10.0)
    assert torch.equal(match_scale(truth * 5, truth, "none"), truth * 5)
    with pytest.raises(ValueError, match="normalize must be one of"):
        match_scale(truth, truth, "peak")


def test_per_depth_curves_find_the_bad_slice(rng):
    truth, _ = _smooth_pair(rng, (4, 24, 24), noise=0.0)
    estimate = truth.copy()
    estimate[2] += 3.0 * rng.standard_normal(truth.shape[1:])
    curves = depth_curves(truth, estimate, depths=[-2e-5, -1e-5, 0.0, 1e-5])
    assert int(torch.argmin(curves.psnr)) == 2 and int(torch.argmin(curves.ssim)) == 2
    assert math.isinf(float(curves.psnr[0])) and float(curves.ssim[0]) == pytest.approx(1.0, abs=1e-12)
    # One data range (the volume's) for every slice: slice 2 matches the whole-volume PSNR computed by hand.
    r = float(truth.max() - truth.min())
    expected = 10 * math.log10(r**2 / np.mean((estimate[2] - truth[2]) ** 2))
    assert float(curves.psnr[2]) == pytest.approx(expected, abs=1e-10)
    assert float(curves.ssim[2]) == pytest.approx(_reference_ssim(truth[2], estimate[2], r), abs=1e-9)
    data = json.loads(json.dumps(curves.to_dict()))
    assert data["psnr_db"][0] is None and data["depths_um"][0] == pytest.approx(-20.0)


def test_compare_report_scale_normalisation_and_json(rng):
    truth, estimate = _smooth_pair(rng, (6, 20, 20), noise=0.5)
    scaled = estimate * 0.01  # an arbitrary reconstruction scale
    plain, fixed = compare(truth, scaled), compare(truth, scaled, normalize="scale", per_depth=True)
    assert fixed.psnr > plain.psnr + 20 and fixed.ssim > plain.ssim
    assert fixed.scale == pytest.approx(100.0, rel=0.01)
    assert fixed.ssim_sigma == (0.0, 1.5, 1.5)  # 6 depths < 11-sample window: no smoothing across z
    data = json.loads(json.dumps(fixed.to_dict()))
    assert set(data) >= {"psnr_db", "ssim", "mse", "data_range", "per_depth", "ssim_sigma_samples"}
    assert len(data["per_depth"]["ssim"]) == 6


def test_lpips_without_package_or_weights_gives_a_clear_message(monkeypatch, tmp_path):
    ok, reason = lpips_available()
    if ok:  # pragma: no cover - only where lpips and its weights are installed
        pytest.skip("LPIPS is installed here")
    with pytest.raises(LPIPSUnavailableError, match=r"nothing is downloaded at run time\. Fix:"):
        lpips(torch.rand(32, 32), torch.rand(32, 32))
    # Packages present but weights absent: the message names the missing files.
    import importlib.machinery

    fake = importlib.machinery.ModuleSpec("lpips", None, is_package=True)
    fake.submodule_search_locations = [str(tmp_path / "lpips")]
    monkeypatch.setattr(perceptual, "_find", lambda name: fake)
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    ok, reason = lpips_available("alex")
    assert not ok and "alexnet-owt-7be5be79.pth" in reason and "weights" in reason and "alex.pth" in reason


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu(rng):
    truth, estimate = _smooth_pair(rng, (12, 24, 20), noise=1.5)
    t, e = torch.from_numpy(truth), torch.from_numpy(estimate)
    for metric in (ssim, psnr, mse):
        cpu, gpu = float(metric(t, e)), metric(t.cuda(), e.cuda())
        assert gpu.device.type == "cuda" and float(gpu) == pytest.approx(cpu, rel=1e-12)  # float64 both sides


def test_the_package_example_runs_on_a_volume_of_few_depths(rng):
    """The module docstring's example, statement by statement, on a bead volume of 5 depths (the napari
    sample's 5 x 93 x 93): an 11-sample SSIM window along z would be refused there."""
    import lfm_studio.engine.image_quality as image_quality

    example = textwrap.dedent(
        image_quality.__doc__.split("Example::\n")[1].split("\n\n\n")[0].split("Read NCC")[0]
    )
    code = "\n".join(line.split("#")[0].rstrip() for line in example.splitlines())
    assert "ssim(" in code and "scorecard(" in code
    truth = torch.zeros(5, 93, 93, dtype=torch.float64)
    for z, y, x in ((0, 20, 30), (2, 46, 46), (4, 70, 60)):
        truth[z, y, x] = 1.0
    estimate = truth + 0.01 * torch.as_tensor(rng.standard_normal(truth.shape))
    namespace = {"truth": truth, "estimate": estimate, "dz": 10e-6, "dy": 0.725e-6, "dx": 0.725e-6}
    exec(compile(code, "image_quality example", "exec"), namespace)
    assert 0.5 < float(namespace["ssim"](truth, estimate, data_range=1.0, sigma=(0, 1.5, 1.5))) < 1.0
