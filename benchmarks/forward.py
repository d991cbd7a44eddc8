"""Forward-model speed: Fourier-LFM PSF stack (per-lenslet vs full sensor grid) and the
conventional-LFM operator (build, forward + back projection).

    python benchmarks/forward.py [--depths 64] [--reference-depths 2] [--quick] [--skip-fourier]

Both paths run in this process on the same design. The full-sensor-grid computation
(relayed pupil x whole MLA on one grid covering the 2048 x 2048 sensor at the same
oversampling, band-limited ASM to the camera, pixel integration) takes tens of seconds
per depth here, so it is timed on ``--reference-depths`` depths spread over the range
and its time per depth is scaled to the full depth count (stated in the table). The
error column is the relative L2 error of the per-lenslet stack against it, per depth.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import torch

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.systems.fourier_psf import FourierPSFReport, fourier_psf_stack
from lfm_studio.engine.systems.from_design import fourier_accuracy_of, fourier_system_of


def _depths(design, count: int) -> tuple[float, ...]:
    start, stop = (v * 1e-6 for v in design.depths.depth_range_um)
    if count == 1:
        return (0.0,)
    return tuple(start + (stop - start) * i / (count - 1) for i in range(count))


def conventional_section(quick: bool) -> None:
    """10x/0.3 preset, 41 x 41 lenslets, 15 px per lenslet, 5x lateral super-sampling, 31 depths +-150 um."""
    from lfm_studio.engine.systems.conventional_psf import conventional_projector
    from lfm_studio.engine.systems.from_design import conventional_system_of

    design = load_preset("lfm_10x_na03")
    lenslets = (15, 15) if quick else (41, 41)
    system = conventional_system_of(design, lenslets=lenslets, pixels_per_lenslet=15, voxels_per_lenslet=5)
    depths = tuple((-150 + 10 * i) * 1e-6 for i in range(31))
    t0 = time.perf_counter()
    projector, _ = conventional_projector(system, depths)
    t_build = time.perf_counter() - t0
    gen = torch.Generator().manual_seed(0)
    volume = torch.rand(projector.volume_shape, generator=gen)
    image = torch.rand(projector.image_shape, generator=gen)
    projector.forward(volume)  # warm-up (allocator, oneDNN kernels)
    t0 = time.perf_counter()
    forward = projector.forward(volume)
    t_forward = time.perf_counter() - t0
    t0 = time.perf_counter()
    back = projector.adjoint(image)
    t_back = time.perf_counter() - t0
    lhs, rhs = (
        float((forward.double() * image.double()).sum()),
        float((volume.double() * back.double()).sum()),
    )
    print(
        f"# conventional {design.name}: {lenslets[0]} x {lenslets[1]} lenslets, 15 px and 5 voxels per lenslet, "
        f"{len(depths)} depths, volume {tuple(projector.volume_shape)}, image {projector.image_shape}"
    )
    print(f"{'stage':<34} {'time (s)':>10}")
    print(f"{'operator build (patterns)':<34} {t_build:>10.2f}")
    print(f"{'forward projection':<34} {t_forward:>10.2f}")
    print(f"{'back projection (adjoint)':<34} {t_back:>10.2f}")
    print(f"{'forward + back':<34} {t_forward + t_back:>10.2f}")
    print(f"(adjoint check <Ax,y>/<x,A^T y> - 1 = {lhs / rhs - 1:.1e})")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--preset", default="xlfm_cong2017")
    parser.add_argument("--depths", type=int, default=64)
    parser.add_argument("--reference-depths", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="8 depths, 1 reference depth, 15 x 15 lenslets")
    parser.add_argument("--skip-fourier", action="store_true")
    parser.add_argument("--skip-conventional", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(2)
    if not args.skip_conventional:
        conventional_section(args.quick)
    if args.skip_fourier:
        return
    if args.quick:
        args.depths, args.reference_depths = 8, 1
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
        accuracy=dataclasses.replace(accuracy, method="per_lenslet"),
        report=report,
    )
    t_fast = time.perf_counter() - t0

    full_acc = dataclasses.replace(accuracy, method="full_field", propagator="bandlimited_asm")
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
