"""Reference image-quality metrics: MSE, PSNR, SSIM (2D/3D), per-depth curves, LPIPS.

Every metric compares an ``estimate`` with a ``truth`` of the same shape (a camera
image ``(Y, X)`` or a volume ``(Z, Y, X)``), is computed in float64 on the inputs'
device and returns a 0-d tensor (differentiable in ``estimate``); numpy arrays are
accepted. The data range of PSNR and SSIM is explicit: by default the truth's
``max - min``, never a dtype's range (the ``255`` of the 8-bit PSNR in thesis eq. 2.3
is used only when passed as ``data_range=255``).

Example::

    from lfm_studio.engine.metrics import compare, psnr, ssim

    psnr(truth, estimate)                     # dB, data range = truth.max() - truth.min()
    ssim(truth, estimate, data_range=1.0)     # Gaussian window, sigma 1.5 (Wang et al. 2004)
    report = compare(truth, estimate, normalize="scale", per_depth=True)
    report.to_dict()                          # JSON-ready numbers
"""

from lfm_studio.engine.metrics.basic import data_range_of, match_scale, mse, psnr
from lfm_studio.engine.metrics.curves import DepthCurves, MetricReport, compare, depth_curves
from lfm_studio.engine.metrics.perceptual import LPIPSUnavailableError, lpips, lpips_available
from lfm_studio.engine.metrics.ssim import gaussian_filter, ssim, ssim_map

__all__ = [
    "DepthCurves",
    "LPIPSUnavailableError",
    "MetricReport",
    "compare",
    "data_range_of",
    "depth_curves",
    "gaussian_filter",
    "lpips",
    "lpips_available",
    "match_scale",
    "mse",
    "psnr",
    "ssim",
    "ssim_map",
]
