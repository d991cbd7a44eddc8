"""How much of the FFT window the XLFM projector's OTFs fill: can a band limit cut the RL transforms?

    PYTHONPATH=. python benchmarks/xlfm_otf_band.py [--pixels 2048] [--depths 4]

Issue #17 asks for an XLFM RL iteration 2x faster than a scipy loop with the same pruned
transforms (``benchmarks/reconstruct.py``). That loop's column transforms alone bound any
bookkeeping gain; only fewer transform points could go past it. If the OTFs were zero outside a
band well inside Nyquist, the forward products and the back projection would need only the
in-band frequencies (output- and input-pruned column transforms over fewer columns). This
script measures, on the benchmark's design (``xlfm_cong2017`` on a square camera, depths over
+-200 um), the largest |OTF| and the |OTF|^2 energy outside square and disk bands of the
camera's frequency plane (cycles per pixel), relative to the peak and to the total, and the
fraction of the ``(Fx/2+1) x Fy`` half plane a square band keeps. Single thread; the OTFs are the
projector's own (``ShiftInvariantProjector.otf_t``).
"""

from __future__ import annotations

import argparse
import warnings

import torch

import lfm_studio  # noqa: F401  # isort: skip  (first: sets OMP_WAIT_POLICY before torch loads)
from benchmarks.reconstruct import _design
from lfm_studio.engine.simulation import imaging_setup, simulate_psf

BANDS = (0.1, 0.2, 0.3, 0.35, 0.4, 0.45)
"""Band edges in cycles per camera pixel (Nyquist is 0.5)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pixels", type=int, default=2048, help="camera side in pixels")
    parser.add_argument("--depths", type=int, default=4, help="depths over -200..200 um")
    args = parser.parse_args()
    torch.set_num_threads(1)
    design = _design("xlfm_cong2017", args.pixels, (-200.0, 200.0), args.depths)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        projector = imaging_setup(simulate_psf(design)).projector
    magnitude = projector.otf_t.abs()  # (Z, Fx/2+1, Fy)
    _, kx_count, fy = magnitude.shape
    ky = torch.fft.fftfreq(fy).abs()
    kx = torch.arange(kx_count) / projector.fft_shape[1]
    peak, energy = float(magnitude.amax()), float(magnitude.pow(2).sum())
    print(
        f"threads: torch 1; {design.name}: camera {args.pixels}^2, {args.depths} depths, window "
        f"{tuple(projector.fft_shape)}, OTF half plane {kx_count} x {fy}"
    )
    print(f"{'band (cycles/px)':<22} {'kept':>6} {'max |OTF| outside / peak':>26} {'energy outside':>15}")
    for edge in BANDS:
        for shape, inside in (
            ("square", (kx[:, None] <= edge) & (ky[None, :] <= edge)),
            ("disk", (kx[:, None] ** 2 + ky[None, :] ** 2) <= edge**2),
        ):
            outside = magnitude[:, ~inside]
            largest = float(outside.amax()) / peak if outside.numel() else 0.0
            print(
                f"{shape + ' <= ' + str(edge):<22} {float(inside.float().mean()):>6.3f} {largest:>26.2e} "
                f"{float(outside.pow(2).sum()) / energy:>15.2e}"
            )


if __name__ == "__main__":
    main()
