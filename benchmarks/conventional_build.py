"""Conventional-LFM build: ours against pyolaf itself and a pyolaf-style numpy reference, time and peak memory.

    python benchmarks/conventional_build.py [--depths 31] [--threads 1 2] [--repeats 1] [--quick]
        [--pyolaf-python /path/to/python-with-pyolaf] [--no-reference] [--busy]

Configuration of issue 17: preset ``lfm_10x_na03`` (10x/0.3, 125 um / 1.875 mm lenslets),
41 x 41 lenslets, 15 px and 5 voxels per lenslet, ``--depths`` depths over +-150 um, the
``standard`` accuracy preset (float32 fields, NIP grid 1.5x: 75 NIP samples per pitch; 3
sensor-field samples per pixel and the exact (Fourier) pixel integral since branch conv-perf,
5 and the midpoint rule before).

- **ours**: ``conventional_psf_stack`` (Debye NIP fields, the lattice FFT Fresnel transform of
  :mod:`lfm_studio.engine.systems.conventional_patterns`, pixel integration).
- **pyolaf** (with ``--pyolaf-python``): pyolaf's own operator build
  (``LFM_computeLFMatrixOperators``: NIP fields, forward and backward patterns) run by that
  interpreter, ``benchmarks/pyolaf_build.py`` (which says what its configuration is and how its
  sampling differs: one sample per pixel, 15 per pitch, against our 75).
- **pyolaf-style reference** (numpy, written here): our model computed the way pyolaf does it,
  per depth and voxel sub-position: the NIP field of the lenslets within reach times the
  microlens transmittance ``exp(-j k (x^2 + y^2) / (2 f))`` (tiled square lenslets), Fresnel
  propagation to the sensor by the 2-D FFT transfer-function method
  ``exp(-j pi lambda d (fx^2 + fy^2))`` on the NIP grid (zero-padded by one pitch on each side),
  ``|U|^2`` on the NIP grid integrated on the pixels by the preset's method (the exact Fourier
  integral: :func:`integrate_pixels` on its 5 x 5 samples per pixel). It uses the engine's NIP
  fields (the Debye part, identical in both, is timed inside the reference too) and the same 6 of
  25 sub-positions (lattice symmetry). Its sensor samples are the NIP grid (75 = 15 x 5 per
  pitch), so since ours samples 3 per pixel the agreement printed is also the error of ours' coarser
  sampling against 5 per pixel.

Each build runs in a fresh process under ``/usr/bin/time -v`` (peak RSS = "Maximum
resident set size"), ours, the reference and pyolaf alternately, for each thread count
(``OMP_NUM_THREADS`` / ``MKL_NUM_THREADS`` / ``OPENBLAS_NUM_THREADS`` and torch's threads; ours
runs ``threads`` workers of 1 intra-op thread each, ``conventional_psf_stack(workers=...)``); the
table gives build seconds, peak GB and the ratios other / ours from the same run. ``--busy``
starts one CPU hog (a Python busy loop in its own process and session) before the first build and
kills it after the last, to show the builds when another job holds a core. The agreement
of our stack with the reference (worst-depth relative L2) is printed once. Nothing here asserts a
time: the machine is shared.
"""

from __future__ import annotations

import lfm_studio  # noqa: F401  # isort: skip  (first: sets OMP_WAIT_POLICY before torch loads, engine/threads.py)
import argparse
import json
import math
import os
import re
import statistics
import subprocess
import sys
import time

import numpy as np
import torch

PRESET = "lfm_10x_na03"


def _system_and_accuracy():
    from lfm_studio.engine.design import load_preset
    from lfm_studio.engine.systems.from_design import conventional_accuracy_of, conventional_system_of

    design = load_preset(PRESET)
    system = conventional_system_of(design, lenslets=(41, 41), pixels_per_lenslet=15, voxels_per_lenslet=5)
    return system, conventional_accuracy_of(design, system)


def _depths(count: int) -> tuple[float, ...]:
    return tuple((-150.0 + 300.0 * i / max(1, count - 1)) * 1e-6 for i in range(count))


def build_ours(depths: tuple[float, ...], workers: int | None = None, device: str = "cpu") -> np.ndarray:
    """Our pattern stack ``(S, S, Z, H, H)`` on ``workers`` threads (default torch's thread count) or
    on ``device`` (``"cuda"``: one item at a time on the GPU), copied back to the host."""
    from lfm_studio.engine.systems.conventional_psf import conventional_psf_stack

    system, accuracy = _system_and_accuracy()
    stack = conventional_psf_stack(system, depths, accuracy=accuracy, workers=workers, device=device)
    return stack.data.cpu().numpy()


def build_reference(depths: tuple[float, ...]) -> np.ndarray:
    """The pyolaf-style stack ``(S, S, Z, H, H)`` (see the module notes), complex128 fields."""
    from lfm_studio.engine.optics.pixel_integration import integrate_pixels
    from lfm_studio.engine.systems.conventional_patterns import nip_fields, samples_per_pitch
    from lfm_studio.engine.systems.conventional_psf import depth_groups

    system, accuracy = _system_and_accuracy()
    s, q = system.voxels_per_lenslet, system.pixels_per_lenslet
    ns = samples_per_pitch(system, accuracy.nip_oversampling)
    m = ns // q  # the reference's sensor sub-samples per pixel: the NIP grid
    if ns != q * m:
        raise ValueError(f"the reference needs NIP samples per pitch ({ns}) a multiple of the pixels ({q}).")
    dx, k = system.pitch / ns, 2.0 * math.pi / system.wavelength
    d, f = system.mla_to_camera, system.lenslet_focal_length
    groups = depth_groups(system, depths)
    width = (2 * max(groups) + 3) * q
    out = np.zeros((s, s, len(depths), width, width), dtype=np.float32)
    half = s // 2
    for reach, indices in groups.items():
        base = nip_fields(
            system, tuple(depths[i] for i in indices), reach=reach, dtype=torch.float64,
            oversampling=accuracy.nip_oversampling,
        ).numpy()  # fmt: skip
        canvas = (2 * reach + 3) * ns
        n = canvas + 2 * ns  # one pitch of zero padding on each side
        x = (np.arange(ns) - ns // 2) * dx
        lens = np.exp(-1j * k * (x[:, None] ** 2 + x[None, :] ** 2) / (2.0 * f))
        mla = np.tile(lens, (2 * reach + 1, 2 * reach + 1))
        freq = np.fft.fftfreq(n, dx)
        transfer = np.exp(-1j * math.pi * system.wavelength * d * (freq[:, None] ** 2 + freq[None, :] ** 2))
        h = (2 * reach + 3) * q
        c = (width - h) // 2
        for a in range(half + 1):
            for b in range(a, half + 1):
                step, field_n = ns // s, base.shape[-1]
                oy, ox = field_n // 2 - a * step, field_n // 2 - b * step
                span = (2 * reach + 1) * ns
                top, left = oy - reach * ns - ns // 2, ox - reach * ns - ns // 2
                for z, index in enumerate(indices):  # one full-field propagation per depth and sub-position
                    plane = np.zeros((n, n), dtype=np.complex128)
                    start = 2 * ns  # region starts one pitch into the canvas, after the padding
                    plane[start : start + span, start : start + span] = (
                        base[z, top : top + span, left : left + span] * mla
                    )
                    sensor = np.fft.ifft2(np.fft.fft2(plane) * transfer)[ns : ns + canvas, ns : ns + canvas]
                    power = (sensor.real**2 + sensor.imag**2) * dx * dx
                    pattern = integrate_pixels(torch.from_numpy(power), m, accuracy.pixel_integration).numpy()
                    for row in {a, -a}:  # the lattice's mirrors and transpose
                        for col in {b, -b}:
                            for r, cc, image in ((row, col, pattern), (col, row, pattern.T)):
                                image = image[::-1] if r < 0 else image
                                image = image[:, ::-1] if cc < 0 else image
                                out[r + half, cc + half, index, c : c + h, c : c + h] = image
    return out


def _child(args) -> None:
    from lfm_studio.engine.allocator import keep_freed_memory

    keep_freed_memory()  # as the CLI does
    torch.set_num_threads(args.threads[0])
    depths = _depths(args.depths)
    gpu = args.device != "cpu"
    if gpu:  # CUDA context and FFT plans are set up once per process: not part of a build
        build_ours(_depths(3), args.threads[0], args.device)
        torch.cuda.synchronize()
        torch.cuda.reset_peak_memory_stats()
    start = time.perf_counter()
    if args.child == "ours":
        data = build_ours(depths, args.threads[0], args.device)  # ends with the copy to the host
    else:
        data = build_reference(depths)
    seconds = time.perf_counter() - start
    if args.save:
        np.save(args.save, data)
    gpu_peak = torch.cuda.max_memory_allocated() / 2**30 if gpu else None
    print(json.dumps({"seconds": seconds, "gpu_peak_gb": gpu_peak}))


def _run(
    which: str, threads: int, depths: int, pyolaf_python: str | None = None, device: str = "cpu"
) -> tuple[float, float, float | None]:
    """Seconds, peak RSS (GB; NaN without ``/usr/bin/time``) and GPU peak (GB, or None) of one build in a
    fresh process."""
    timer = ["/usr/bin/time", "-v"] if os.path.exists("/usr/bin/time") else []
    if which == "pyolaf":
        script = os.path.join(os.path.dirname(os.path.abspath(__file__)), "pyolaf_build.py")
        command = [*timer, pyolaf_python, script, "--depths", str(depths)]
    else:
        command = [*timer, sys.executable, __file__, "--child", which, "--threads", str(threads)]
        command += ["--depths", str(depths), "--device", device]
    count = str(threads)
    env = {**os.environ, "OMP_NUM_THREADS": count, "MKL_NUM_THREADS": count, "OPENBLAS_NUM_THREADS": count}
    result = subprocess.run(command, capture_output=True, text=True, check=True, env=env)
    report = json.loads(result.stdout.strip().splitlines()[-1])
    peak = re.search(r"Maximum resident set size \(kbytes\): (\d+)", result.stderr)
    peak_gb = int(peak.group(1)) / 2**20 if peak else math.nan
    return report["seconds"], peak_gb, report.get("gpu_peak_gb")


def _start_hog() -> subprocess.Popen:
    """One process that keeps a core busy (a Python busy loop) until :func:`_stop_hog`, in its own
    session, like another user's job: with Linux's autogroup scheduling (``sched_autogroup_enabled``)
    each session gets a fair share of the cores, so a hog in the benchmark's own session would take
    only a third of them from a 2-worker build, one in its own session takes a core."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)


def _stop_hog(hog: subprocess.Popen | None) -> str:
    """Kill the hog; say whether it ran (alive until the end) and its CPU seconds."""
    if hog is None:
        return "none"
    alive = hog.poll() is None
    cpu = _cpu_seconds(hog.pid)
    hog.kill()
    hog.wait()
    return f"ran to the end ({cpu:.0f} CPU s)" if alive else f"died early (exit {hog.returncode})"


def _cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a running process (Linux ``/proc``; NaN elsewhere)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
    except OSError:
        return math.nan
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--depths", type=int, default=31)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--quick", action="store_true", help="7 depths, 1 thread")
    parser.add_argument(
        "--pyolaf-python", help="an interpreter with pyolaf installed: time pyolaf itself too"
    )
    parser.add_argument("--no-reference", action="store_true", help="skip the numpy pyolaf-style reference")
    parser.add_argument("--busy", action="store_true", help="one CPU-hog process runs during the builds")
    parser.add_argument(
        "--device",
        default="cpu",
        help="where ours builds (cuda: after a warm-up build; scripts/gpu_check.sh)",
    )
    parser.add_argument("--child", choices=("ours", "reference"), help=argparse.SUPPRESS)
    parser.add_argument("--save", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        _child(args)
        return
    if args.quick:
        args.depths, args.threads = 7, [1]
    if args.device != "cpu" and not torch.cuda.is_available():
        print(
            f"# --device {args.device}: CUDA is not available here (torch.cuda.is_available() is False); nothing timed"
        )
        return
    from lfm_studio.engine.threads import available_cores

    print(
        f"# {PRESET}, 41 x 41 lenslets, 15 px / 5 voxels per lenslet, {args.depths} depths over +-150 um, "
        f"standard preset; ours on {args.device}; threads {args.threads} of {available_cores()} cores (ours "
        f"on the CPU: that many workers of 1 intra-op thread), "
        f"OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY', 'unset')}; fresh process per build; "
        f"load average {os.getloadavg()[0]:.2f} at the start"
    )
    others = ([] if args.no_reference else ["reference"]) + (["pyolaf"] if args.pyolaf_python else [])
    results: dict[tuple[str, int], list[tuple[float, float, float | None]]] = {}
    hog = _start_hog() if args.busy else None
    try:
        for _ in range(args.repeats):
            for threads in args.threads:
                for which in ["ours", *others]:
                    results.setdefault((which, threads), []).append(
                        _run(which, threads, args.depths, args.pyolaf_python, args.device)
                    )
    finally:
        hog_ran = _stop_hog(hog)
    print(f"# load average {os.getloadavg()[0]:.2f} at the end; times: median of {args.repeats}; peak: max")
    print(f"# CPU hog during the builds: {hog_ran}")
    columns = ["threads", "ours s", *(f"{o} {c}" for o in others for c in ("s", "/ ours")), "ours peak GB"]
    columns += [f"{o} peak GB" for o in others]
    gpu = args.device != "cpu"
    columns += ["ours GPU peak GB"] if gpu else []
    print("| " + " | ".join(columns) + " |")
    print("|" + "---|" * len(columns))
    for threads in args.threads:
        ours = results[("ours", threads)]
        t_ours, m_ours = statistics.median(r[0] for r in ours), max(r[1] for r in ours)
        cells = [f"{threads}", f"{t_ours:.2f}"]
        peaks = [f"{m_ours:.3f}"]
        for other in others:
            rows = results[(other, threads)]
            t_other = statistics.median(r[0] for r in rows)
            cells += [f"{t_other:.2f}", f"{t_other / t_ours:.2f}"]
            peaks.append(f"{max(r[1] for r in rows):.3f}")
        peaks += [f"{max(r[2] or 0.0 for r in ours):.3f}"] if gpu else []
        print("| " + " | ".join(cells + peaks) + " |")
    if gpu:  # the same build on the GPU and on the CPU
        a, b = build_ours(_depths(args.depths), device=args.device), build_ours(_depths(args.depths))
        print(f"agreement ours on {args.device} vs ours on the CPU: {_worst_depth_error(a, b)}")
    if not args.no_reference:
        a, b = build_ours(_depths(args.depths)), build_reference(_depths(args.depths))
        print(f"agreement ours vs reference: {_worst_depth_error(a, b)}")


def _worst_depth_error(a: np.ndarray, b: np.ndarray) -> str:
    """Worst and median over depths of the relative L2 error of stack ``a`` against ``b`` ``(S, S, Z, H, H)``."""
    errors = [
        float(np.linalg.norm(a[:, :, z] - b[:, :, z]) / np.linalg.norm(b[:, :, z])) for z in range(a.shape[2])
    ]
    return f"worst-depth relative L2 {max(errors):.2e} (median {np.median(errors):.2e})"


if __name__ == "__main__":
    main()
