"""Fourier projector set-up time against the number of depths: chunked (ours) vs whole-stack.

    python benchmarks/projector_setup.py [--pixels 1024] [--volume 512] [--depths 8 16 32] \
        [--threads 1] [--repeats 3]

``ShiftInvariantProjector.__init__`` computes the PSF spectra (OTFs). It used to transform
the whole stack at once (a row ``rfft`` of every depth, one transpose copy, a column
``fft``), whose working set outgrows the cache as depths are added; it now runs the same
passes chunk by chunk of depths, as ``forward()`` does. The whole-stack version is kept
here (:func:`whole_stack_otf`, the previous code) as the in-process baseline. Timings
alternate between the two (other jobs share this machine) and the table gives medians,
the time per depth and the ratio whole-stack / chunked measured in the same run. Both
results are compared (max relative difference). PSFs are random non-negative (the time
does not depend on their values), float32, ``pixels x pixels``; volumes ``volume^2``.
"""

from __future__ import annotations

import lfm_studio  # noqa: F401  # isort: skip  (first: sets OMP_WAIT_POLICY before torch loads, engine/threads.py)
import argparse
import statistics
import time

import torch

from lfm_studio.engine import fft
from lfm_studio.engine.allocator import keep_freed_memory
from lfm_studio.engine.operators import ShiftInvariantProjector
from lfm_studio.engine.threads import describe_threads, torch_threads


def whole_stack_otf(psf: torch.Tensor, fft_shape: tuple[int, int]) -> torch.Tensor:
    """The previous set-up: every depth in one batch, transposed layout ``(Z, Fx//2+1, Fy)``."""
    fy, fx = fft_shape
    rows = fft.rfft_along(psf, fx, dim=-1).transpose(-2, -1).contiguous()
    return fft.fft_along(rows, fy, dim=-1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pixels", type=int, default=1024, help="camera side (PSF is pixels x pixels)")
    parser.add_argument("--volume", type=int, default=512, help="volume lateral side in voxels")
    parser.add_argument("--depths", type=int, nargs="+", default=[8, 16, 32])
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    keep_freed_memory()  # as the CLI does
    with torch_threads(args.threads):
        print(describe_threads())
        print(f"camera {args.pixels}^2 px, volume {args.volume}^2 voxels, float32, median of {args.repeats}")
        print("| depths | whole-stack s | chunked s | chunked ms/depth | whole / chunked | max rel diff |")
        print("|---|---|---|---|---|---|")
        generator = torch.Generator().manual_seed(0)
        for depths in args.depths:
            psf = torch.rand((depths, args.pixels, args.pixels), generator=generator)
            ours, old = [], []
            for _ in range(args.repeats):
                start = time.perf_counter()
                projector = ShiftInvariantProjector(psf, (args.volume, args.volume))
                ours.append(time.perf_counter() - start)
                start = time.perf_counter()
                reference = whole_stack_otf(psf, projector.fft_shape)
                old.append(time.perf_counter() - start)
            diff = float((projector.otf_t - reference).abs().max() / reference.abs().max())
            t_new, t_old = statistics.median(ours), statistics.median(old)
            print(
                f"| {depths} | {t_old:.3f} | {t_new:.3f} | {1e3 * t_new / depths:.1f} | "
                f"{t_old / t_new:.2f} | {diff:.1e} |"
            )
            del projector, reference, psf


if __name__ == "__main__":
    main()
