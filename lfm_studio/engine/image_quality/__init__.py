"""Reconstruction quality: NCC, peak F1, MSE, PSNR, SSIM (2D/3D), per-depth curves, LPIPS, floors.

Every metric compares an ``estimate`` with a ``truth`` of the same shape (a camera
image ``(Y, X)`` or a volume ``(Z, Y, X)``), is computed in float64 on the inputs'
device and returns a 0-d tensor (differentiable in ``estimate``); numpy arrays are
accepted. The data range of PSNR and SSIM is explicit: by default the truth's
``max - min``, never a dtype's range (the ``255`` of the 8-bit PSNR in thesis eq. 2.3
is used only when passed as ``data_range=255``).

Example::

    from lfm_studio.engine.image_quality import compare, psnr, scorecard, ssim

    psnr(truth, estimate)                     # dB, data range = truth.max() - truth.min()
    ssim(truth, estimate, data_range=1.0, sigma=(0, 1.5, 1.5))  # Gaussian window of sigma 1.5 (Wang et al.
                                              # 2004) in y and x, none across z: the window needs 11 samples
                                              # per axis, a volume of few depths has fewer (compare and
                                              # scorecard choose this by themselves)
    report = compare(truth, estimate, normalize="scale", per_depth=True)
    report.to_dict()                          # JSON-ready numbers

    card = scorecard(truth, estimate, normalize="scale", voxel_size=(dz, dy, dx))
    card.summary(noun="beads")                # "NCC 0.82  F1 0.90 (9/10 beads)  PSNR 36.41 dB (zero floor ..."
    card.table()                              # each score beside the all-zero and constant volumes' scores

Read NCC and F1 first: on a sparse phantom the all-zero volume already scores a high
PSNR and an SSIM near 1 (see :mod:`.floors`).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from lfm_studio.engine.image_quality.basic import NORMALIZATIONS, data_range_of, match_scale, mse, psnr
from lfm_studio.engine.image_quality.correlation import ncc
from lfm_studio.engine.image_quality.curves import DepthCurves, MetricReport, compare, depth_curves
from lfm_studio.engine.image_quality.floors import FLOORS, floor_volume, shuffled
from lfm_studio.engine.image_quality.matching import PeakMatch, match_peaks, peak_match
from lfm_studio.engine.image_quality.peaks import Peaks, find_peaks, looks_point_like
from lfm_studio.engine.image_quality.perceptual import LPIPSUnavailableError, lpips, lpips_available
from lfm_studio.engine.image_quality.scorecard import (
    NORMALIZATION_TEXT,
    PeakOptions,
    Score,
    Scorecard,
    scorecard,
)
from lfm_studio.engine.image_quality.ssim import gaussian_filter, ssim, ssim_map

__all__ = [
    "FLOORS",
    "NORMALIZATIONS",
    "NORMALIZATION_TEXT",
    "DepthCurves",
    "LPIPSUnavailableError",
    "MetricReport",
    "PeakMatch",
    "PeakOptions",
    "Peaks",
    "Score",
    "Scorecard",
    "compare",
    "data_range_of",
    "depth_curves",
    "find_peaks",
    "floor_volume",
    "gaussian_filter",
    "looks_point_like",
    "lpips",
    "lpips_available",
    "match_peaks",
    "match_scale",
    "mse",
    "ncc",
    "peak_match",
    "psnr",
    "scorecard",
    "shuffled",
    "ssim",
    "ssim_map",
]
