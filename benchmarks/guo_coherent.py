"""Guo-style touching lenslets: coherent per-lenslet path against the full sensor field.

    python benchmarks/guo_coherent.py [--threads 1] [--depths 8] [--full-depths 2] [--skip-accuracy]

``flfm_guo2019``'s square lenslets touch, so their footprints overlap on the sensor and the
sub-images interfere. Two fast paths: ``per_lenslet_coherent`` (each lenslet's complex field on
one shared canvas, summed, ``|.|^2`` once) and the full field on the sensor crop the lenslet
windows cover; "auto" takes the cheaper (for Guo: the cropped full field).

1. Accuracy (``--skip-accuracy`` to skip): the bench case (a centred 512^2 crop holding the
   whole array's footprint; depths -40, 0, 40 um), each accuracy preset, "auto", the coherent
   path and the full field at that preset's knobs, both against the converged reference of
   ``lfm-studio bench`` (full field, s = 6, float64); the worst-depth relative L2 error
   and the preset's bound. Also the intensity sum (``per_lenslet``) for comparison.
2. Time at the full 2048^2 sensor, preview and standard preset knobs: "auto" and the coherent
   path on ``--depths`` depths, the whole-sensor full field on ``--full-depths`` of them
   (seconds per depth, ratios), and their relative difference on those depths. Same process, same thread count; the
   load average is printed (the machine is shared).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

import torch

from lfm_studio.bench.cases import bench_case
from lfm_studio.bench.compute import depth_first, reference_stack
from lfm_studio.bench.knobs import preset_options, reference_plan
from lfm_studio.engine.design import load_preset
from lfm_studio.engine.design.accuracy import PRESET_ERROR_BOUNDS
from lfm_studio.engine.systems.fourier_psf import FourierPSFReport, fourier_psf_stack
from lfm_studio.engine.systems.from_design import fourier_system_of


def _errors(a: torch.Tensor, b: torch.Tensor) -> list[float]:
    a, b = a.double(), b.double()
    return [float((a[i] - b[i]).norm() / b[i].norm()) for i in range(b.shape[0])]


def _timed(system, depths, accuracy):
    report = FourierPSFReport()
    t0 = time.perf_counter()
    stack = fourier_psf_stack(system, depths, accuracy=accuracy, report=report)
    return stack, time.perf_counter() - t0, report


def accuracy_section() -> None:
    case = bench_case(load_preset("flfm_guo2019"), "flfm_guo2019")
    system = fourier_system_of(case.design)
    t0 = time.perf_counter()
    reference = depth_first(reference_stack(case, reference_plan(case)))
    print(f"# accuracy: {case.note}; depths {[round(z * 1e6) for z in case.depths]} um")
    print(
        f"# reference: {reference_plan(case)[0][0].method}, s = 6, float64 ({time.perf_counter() - t0:.1f} s)"
    )
    print(f"{'preset':<10} {'method':<34} {'time (s)':>9} {'max error':>10} {'bound':>7}")
    for preset in ("preview", "standard", "reference"):
        acc = preset_options(case, preset)
        for method in ("auto", "per_lenslet_coherent", "full_field", "per_lenslet"):
            stack, seconds, _ = _timed(system, case.depths, dataclasses.replace(acc, method=method))
            error = max(_errors(depth_first(stack), reference))
            bound = PRESET_ERROR_BOUNDS["fourier"][preset]
            label = method if method != "auto" else f"auto = {_label(stack)}"
            print(f"{preset:<10} {label:<34} {seconds:>9.2f} {error:>10.2e} {bound:>7.3f}")


def _label(stack) -> str:
    pixels = stack.metadata.get("full_field_pixels")
    return stack.metadata["method"] + (f" {pixels[0]}x{pixels[1]}" if pixels else "")


def timing_section(depth_count: int, full_count: int) -> None:
    design = load_preset("flfm_guo2019")
    system = fourier_system_of(design)
    start, stop = (v * 1e-6 for v in design.depths.depth_range_um)
    depths = tuple(start + (stop - start) * i / max(1, depth_count - 1) for i in range(depth_count))
    picks = [round(i * (depth_count - 1) / max(1, full_count - 1)) for i in range(full_count)]
    if full_count == 1:
        picks = [depth_count // 2]
    full_depths = tuple(depths[i] for i in picks)
    ny, nx = system.sensor_shape
    print(f"# time: {design.name}, {len(system.mla)} lenslets, {ny} x {nx} sensor; seconds per depth")
    print(
        f"{'preset':<10} {'whole full field':>16} {'auto':>24} {'coherent':>9} {'whole/auto':>11} "
        f"{'whole/coh.':>11} {'auto vs whole':>14} {'coh. vs whole':>14}"
    )
    for preset in ("preview", "standard"):
        acc = preset_options(bench_case(design, "g"), preset)  # (no crop: the case is only for knobs)
        coherent_acc = dataclasses.replace(acc, method="per_lenslet_coherent")
        fourier_psf_stack(system, depths[:1], accuracy=acc)  # warm-up (allocator, FFT plans)
        fourier_psf_stack(system, depths[:1], accuracy=coherent_acc)
        auto, t_auto, _ = _timed(system, depths, acc)
        coherent, t_coherent, _ = _timed(system, depths, coherent_acc)
        whole, t_whole, _ = _timed(system, full_depths, dataclasses.replace(acc, method="full_field"))
        t_auto, t_coherent, t_whole = (
            t_auto / len(depths),
            t_coherent / len(depths),
            t_whole / len(full_depths),
        )
        d_auto = max(_errors(auto.data[picks], whole.data))
        d_coherent = max(_errors(coherent.data[picks], whole.data))
        print(
            f"{preset:<10} {t_whole:>16.2f} {t_auto:>9.3f} ({_label(auto):>12}) {t_coherent:>9.3f} "
            f"{t_whole / t_auto:>10.1f}x {t_whole / t_coherent:>10.1f}x {d_auto:>14.2e} {d_coherent:>14.2e}"
        )
    print(
        f"(auto and coherent on {len(depths)} depths, the whole full field on {len(full_depths)}: "
        f"{[f'{z * 1e6:.0f} um' for z in full_depths]}; 'vs whole': relative L2 difference on those depths)"
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--depths", type=int, default=8)
    parser.add_argument("--full-depths", type=int, default=2)
    parser.add_argument("--skip-accuracy", action="store_true")
    parser.add_argument("--skip-timing", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    print(
        f"# torch threads {torch.get_num_threads()}, {os.cpu_count()} CPUs, load average {load} (1, 5, 15 min)"
    )
    if not args.skip_accuracy:
        accuracy_section()
    if not args.skip_timing:
        timing_section(args.depths, args.full_depths)
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    print(f"# load average at the end {load}")


if __name__ == "__main__":
    main()
