"""Forward-model speed: the XLFM-like preset's PSF stack, per-lenslet vs full sensor grid.

    python benchmarks/forward.py [--depths 64] [--reference-depths 2] [--quick]

Both paths run in this process on the same design. The full-sensor-grid computation
(relayed pupil x whole MLA on one grid covering the 2048 x 2048 sensor at the same
oversampling, band-limited ASM to the camera, pixel integration) takes tens of seconds
per depth here, so it is timed on ``--reference-depths`` depths spread over the range
and its time per depth is scaled to the full depth count (stated in the table). The
error column is the relative L2 error of the per-lenslet stack against it, per depth.
"""

from __future__ import annotations

import argparse
import time

import torch

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.systems.fourier_psf import FourierAccuracy, FourierPSFReport, fourier_psf_stack
from lfm_studio.engine.systems.from_design import fourier_accuracy_of, fourier_system_of


def _depths(design, count: int) -> tuple[float, ...]:
    start, stop = (v * 1e-6 for v in design.depths.depth_range_um)
    if count == 1:
        return (0.0,)
    return tuple(start + (stop - start) * i / (count - 1) for i in range(count))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--preset", default="xlfm_cong2017")
    parser.add_argument("--depths", type=int, default=64)
    parser.add_argument("--reference-depths", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="8 depths, 1 reference depth")
    args = parser.parse_args()
    if args.quick:
        args.depths, args.reference_depths = 8, 1
    torch.set_num_threads(2)
    design = load_preset(args.preset)
    system = fourier_system_of(design)
    accuracy = fourier_accuracy_of(design)
    depths = _depths(design, args.depths)
    picks = [
        round(i * (len(depths) - 1) / max(1, args.reference_depths - 1)) for i in range(args.reference_depths)
    ]
    if args.reference_depths == 1:
        picks = [len(depths) // 2]
    ref_depths = tuple(depths[i] for i in picks)

    report = FourierPSFReport()
    t0 = time.perf_counter()
    fast = fourier_psf_stack(
        system,
        depths,
        accuracy=FourierAccuracy(**{**accuracy.__dict__, "method": "per_lenslet"}),
        report=report,
    )
    t_fast = time.perf_counter() - t0

    full_acc = FourierAccuracy(
        **{**accuracy.__dict__, "method": "full_field", "propagator": "bandlimited_asm"}
    )
    t0 = time.perf_counter()
    full = fourier_psf_stack(system, ref_depths, accuracy=full_acc)
    t_full_per_depth = (time.perf_counter() - t0) / len(ref_depths)
    t_full = t_full_per_depth * len(depths)

    errors = [float((fast.data[i] - full.data[k]).norm() / full.data[k].norm()) for k, i in enumerate(picks)]
    ny, nx = system.sensor_shape
    print(
        f"# {design.name}: {len(system.mla)} lenslets, {ny} x {nx} sensor, {len(depths)} depths, "
        f"oversampling {accuracy.oversampling}, {accuracy.model} objective, {accuracy.dtype}"
    )
    print(f"{'method':<34} {'time (s)':>10} {'ratio':>8} {'max rel. L2 error':>18}")
    print(f"{'full sensor grid (baseline)':<34} {t_full:>10.1f} {1.0:>8.2f} {'reference':>18}")
    print(f"{'  measured per depth':<34} {t_full_per_depth:>10.2f} {'':>8} {'':>18}")
    print(f"{'per-lenslet small grids':<34} {t_fast:>10.1f} {t_full / t_fast:>8.1f}x {max(errors):>18.2e}")
    print(
        f"(baseline timed on {len(ref_depths)} depth(s) {[f'{z * 1e6:.0f} um' for z in ref_depths]}, "
        f"scaled to {len(depths)}; errors per depth: {[f'{e:.2e}' for e in errors]})"
    )


if __name__ == "__main__":
    main()
