"""Reconstruction speed: one 3D Richardson-Lucy iteration against scipy loops, and time to quality.

    python benchmarks/reconstruct.py [--quick] [--threads 1 2] [--pixels 2048] [--depths 64] [--repeats 3]
        [--photons 100] [--metric ncc]

Every run prints its thread settings (torch threads, cores, OMP_WAIT_POLICY).

(a) XLFM preset (xlfm_cong2017), ``--pixels`` square camera (2048), ``--depths`` depths, the
    design's field of view: one RL iteration (forward projection, ratio, back projection,
    update) of ``lfm_studio.engine.reconstruct`` against baselines written here and run in
    the same process on the same data with the same thread count (several ``--threads``
    values are interleaved: torch threads = scipy FFT workers):
    (i)   the baseline: a *pruned* ``scipy.fft`` loop with the projector's cached OTFs and the
          same pruning (row transforms on the rows a slice fills, inverse column transforms
          cropped before the row inverse; transposed contiguous layout);
    (ii)  an unpruned cached-OTF ``scipy.fft`` loop: rfft2/irfft2 per depth on the same window;
    (iii) a per-depth ``scipy.signal.fftconvolve`` loop (full convolution, cropped; valid
          correlation for the back projection), which recomputes every FFT;
    (floor) the column transforms alone (two ``(Fx/2+1) x Fy`` complex FFTs per depth): work any
          projector with these pruned transforms does, so (i) / (floor) bounds what bookkeeping
          can gain over (i).
    Timings alternate between methods (other jobs share this machine); the table gives the
    median over ``--repeats`` and the ratios of those medians. Goal: ours >= 2x faster
    than (i). The baselines' A x and A^T y are checked against the engine projector's.
(b) Time to reach the quality (``--metric`` PSNR or NCC against the truth) that 30 and 100
    plain RL iterations reach, on a smaller problem (FLFM preset, 512 x 512 camera, 9 depths
    over +-40 um, 6 beads; noise-free or ``--photons`` at the brightest pixel, Poisson): plain,
    Biggs-Andrews, geometric, Wiener-Butterworth back projector and combinations, advanced in
    lockstep (one iteration each in turn, same load); time = back-projector build +
    iterations x the method's median iteration time. Goal: <= 1/4 of plain RL's time for the
    100-iteration target (1/3 of the 30-iteration one with ``--quick``).
(c) With CUDA: the (a) iteration on the GPU (goal <= 20 ms on an H100), after checking its
    ``A x`` against the CPU projector's. ``--cuda-only`` skips the CPU timings of (a) (the device
    machine's run, ``scripts/gpu_check.sh``).

``--quick`` (about a minute): (a) with 4 depths, (b) with a 256 px camera and the 30-iteration target.
"""

from __future__ import annotations

import lfm_studio  # noqa: F401  # isort: skip  (first: sets OMP_WAIT_POLICY before torch loads, engine/threads.py)
import argparse
import statistics
import time
import warnings

import numpy as np
import scipy.fft
import scipy.signal
import torch

from lfm_studio.engine.allocator import keep_freed_memory
from lfm_studio.engine.design import load_preset
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.phantoms import beads
from lfm_studio.engine.reconstruct import (
    accelerated_rl_options,
    richardson_lucy_iterates,
    wiener_butterworth_backprojector,
)
from lfm_studio.engine.reconstruct.fourier_geometry import centre_offsets
from lfm_studio.engine.simulation import imaging_setup, simulate_psf
from lfm_studio.engine.threads import describe_threads


def _design(name: str, pixels: int, depth_range_um: tuple[float, float], count: int):
    design = load_preset(name)
    camera = type(design.camera)(**{**design.camera.model_dump(), "pixel_count": (pixels, pixels)})
    step = (depth_range_um[1] - depth_range_um[0]) / max(1, count - 1)
    depths = type(design.depths)(depth_range_um=depth_range_um, depth_step_um=step)
    return design.updated(camera=camera, depths=depths)


class ScipyOTFLoop:
    """RL iteration with scipy.fft per depth on the projector's FFT window and cached OTFs."""

    def __init__(self, projector, workers: int) -> None:
        self.otf = projector.otf.numpy()  # shared memory, computed once
        self.fft_shape = tuple(projector.fft_shape)
        self.offsets = centre_offsets(projector)
        self.image_shape = tuple(projector.image_shape)
        self.volume_shape = tuple(projector.volume_shape)
        self.workers = workers

    def forward(self, volume: np.ndarray) -> np.ndarray:
        _, vy, vx = self.volume_shape
        total = None
        padded = np.zeros(self.fft_shape, dtype=volume.dtype)
        for z in range(volume.shape[0]):
            padded[:vy, :vx] = volume[z]
            term = scipy.fft.rfft2(padded, workers=self.workers) * self.otf[z]
            total = term if total is None else total + term
        full = scipy.fft.irfft2(total, s=self.fft_shape, workers=self.workers)
        (oy, ox), (py, px) = self.offsets, self.image_shape
        return full[oy : oy + py, ox : ox + px]

    def adjoint(self, image: np.ndarray) -> np.ndarray:
        (oy, ox), (py, px) = self.offsets, self.image_shape
        embedded = np.zeros(self.fft_shape, dtype=image.dtype)
        embedded[oy : oy + py, ox : ox + px] = image
        spectrum = scipy.fft.rfft2(embedded, workers=self.workers)
        z, vy, vx = self.volume_shape
        out = np.empty((z, vy, vx), dtype=image.dtype)
        for k in range(z):
            out[k] = scipy.fft.irfft2(spectrum * self.otf[k].conj(), s=self.fft_shape, workers=self.workers)[
                :vy, :vx
            ]
        return out


class ScipyPrunedLoop:
    """RL iteration with scipy.fft per depth, pruned as the engine's projector is (the baseline).

    Same window, cached OTFs (in the projector's transposed layout ``(Fx//2+1, Fy)``, so every
    1D pass runs along contiguous memory) and the same pruning: the row ``rfft`` runs on the
    ``Vy`` rows a slice fills, the inverse column transform is cropped to the sensor rows
    before the row ``irfft``; the back projection transforms the image once and crops each
    depth's inverse to the ``Vy`` volume rows before its row ``irfft``.
    """

    def __init__(self, projector, workers: int) -> None:
        self.otf_t = projector.otf_t.numpy()  # shared memory, computed once
        self.fft_shape = tuple(projector.fft_shape)
        self.offsets = centre_offsets(projector)
        self.image_shape = tuple(projector.image_shape)
        self.volume_shape = tuple(projector.volume_shape)
        self.workers = workers

    def forward(self, volume: np.ndarray) -> np.ndarray:
        (fy, fx), w = self.fft_shape, self.workers
        total = None
        for z in range(volume.shape[0]):
            rows = np.ascontiguousarray(scipy.fft.rfft(volume[z], n=fx, axis=-1, workers=w).T)  # (Kx, Vy)
            term = scipy.fft.fft(rows, n=fy, axis=-1, workers=w) * self.otf_t[z]
            total = term if total is None else total + term
        (oy, ox), (py, px) = self.offsets, self.image_shape
        columns = scipy.fft.ifft(total, axis=-1, workers=w)[:, oy : oy + py]  # (Kx, Py)
        image = scipy.fft.irfft(np.ascontiguousarray(columns.T), n=fx, axis=-1, workers=w)
        return image[:, ox : ox + px]

    def adjoint(self, image: np.ndarray) -> np.ndarray:
        (fy, fx), w = self.fft_shape, self.workers
        (oy, ox), (py, px) = self.offsets, self.image_shape
        z, vy, vx = self.volume_shape
        embedded = np.zeros((py, fx), dtype=image.dtype)
        embedded[:, ox : ox + px] = image
        rows = scipy.fft.rfft(embedded, axis=-1, workers=w).T  # (Kx, Py)
        padded = np.zeros((rows.shape[0], fy), dtype=rows.dtype)
        padded[:, oy : oy + py] = rows
        spectrum = scipy.fft.fft(padded, axis=-1, workers=w)
        out = np.empty((z, vy, vx), dtype=image.dtype)
        for k in range(z):
            columns = scipy.fft.ifft(spectrum * self.otf_t[k].conj(), axis=-1, workers=w)[:, :vy]
            out[k] = scipy.fft.irfft(np.ascontiguousarray(columns.T), n=fx, axis=-1, workers=w)[:, :vx]
        return out


class ColumnTransformFloor:
    """The column transforms alone: two ``(Fx/2+1) x Fy`` complex ``scipy.fft`` transforms per depth.

    Every projector that runs the pruned transforms of the engine and of the baseline (i) does
    this much work per RL iteration: the forward column FFT of each depth's row spectra and the
    back projection's column inverse of each depth's product (the row transforms touch only the
    ``Vy`` volume rows and are ~7x smaller at the XLFM preset). ``time(i) / time(floor)`` bounds
    the speed-up any bookkeeping (layouts, fused passes, buffers) can buy over (i) with these
    transforms; beyond it the transforms themselves must shrink (fewer points, pruned FFTs).
    """

    def __init__(self, projector, workers: int) -> None:
        kx, fy = projector.otf_t.shape[1:]
        self.block = np.random.default_rng(0).standard_normal((kx, fy)).astype(np.complex64)
        self.depths = projector.volume_shape[0]
        self.workers = workers

    def iteration(self) -> None:
        for _ in range(self.depths):
            scipy.fft.fft(self.block, axis=-1, workers=self.workers)  # forward: column FFT
            scipy.fft.ifft(self.block, axis=-1, workers=self.workers)  # back projection: column inverse


class ScipyFFTConvolveLoop:
    """RL iteration with scipy.signal.fftconvolve per depth (no cached spectra)."""

    def __init__(self, psf: np.ndarray, projector, workers: int) -> None:
        self.psf, self.flipped = psf, psf[:, ::-1, ::-1].copy()
        self.offsets = centre_offsets(projector)
        self.full_shape = tuple(projector.full_shape)
        self.image_shape = tuple(projector.image_shape)
        self.workers = workers

    def forward(self, volume: np.ndarray) -> np.ndarray:
        with scipy.fft.set_workers(self.workers):
            full = sum(
                scipy.signal.fftconvolve(volume[z], self.psf[z], mode="full") for z in range(len(volume))
            )
        (oy, ox), (py, px) = self.offsets, self.image_shape
        return full[oy : oy + py, ox : ox + px]

    def adjoint(self, image: np.ndarray) -> np.ndarray:
        (oy, ox), (py, px) = self.offsets, self.image_shape
        embedded = np.zeros(self.full_shape, dtype=image.dtype)
        embedded[oy : oy + py, ox : ox + px] = image
        with scipy.fft.set_workers(self.workers):
            return np.stack([scipy.signal.fftconvolve(embedded, h, mode="valid") for h in self.flipped])


def numpy_rl_iteration(op, volume: np.ndarray, image: np.ndarray, sensitivity: np.ndarray) -> np.ndarray:
    """The same update as ours: x * max(A^T(y / max(Ax, floor)), 0) / max(A^T 1, floor)."""
    floor = 16 * np.finfo(np.float32).eps
    predicted = np.maximum(op.forward(volume), floor * image.max())
    correction = np.maximum(op.adjoint(image / predicted), 0.0)
    return volume * correction / np.maximum(sensitivity, floor * sensitivity.max())


def section_iteration(args) -> None:
    pixels, depths = args.pixels, (4 if args.quick else args.depths)
    design = _design("xlfm_cong2017", pixels, (-200.0, 200.0), depths)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        stack = simulate_psf(design)
    t_psf = time.perf_counter() - t0
    t0 = time.perf_counter()
    setup = imaging_setup(stack)
    t_setup = time.perf_counter() - t0
    projector = setup.projector
    generator = torch.Generator().manual_seed(0)
    # A sparse-ish random volume and its image with a faint floor (timings do not depend on the content).
    truth = torch.rand(setup.volume_shape, generator=generator) ** 8
    image = projector.forward(truth).clamp_min(0.0) + 1e-3 * torch.rand(
        projector.image_shape, generator=generator
    )
    volume = torch.rand(setup.volume_shape, generator=generator) + 0.5
    print(
        f"# (a) {design.name}: camera {pixels} x {pixels}, {depths} depths, "
        f"volume {tuple(setup.volume_shape)}, FFT window {tuple(projector.fft_shape)}, float32; "
        f"PSF stack {t_psf:.1f} s, projector set-up {t_setup:.2f} s; threads {args.threads} (interleaved)"
    )
    if args.cuda_only:
        if torch.cuda.is_available():
            section_cuda(stack, setup, image, volume)
        else:
            print("(c) CUDA: not available here (torch.cuda.is_available() is False); nothing timed")
        return
    y, x = image.numpy(), volume.numpy()
    loops = {
        "pruned": ScipyPrunedLoop(projector, 1),
        "otf": ScipyOTFLoop(projector, 1),
        "convolve": ScipyFFTConvolveLoop(stack.data.numpy(), projector, 1),
    }
    sensitivity = loops["pruned"].adjoint(np.ones_like(y))
    forward, back = projector.forward(volume).numpy(), projector.adjoint(image).numpy()
    diffs = {}
    for key, op in loops.items():  # same operators: A x and A^T y against the engine's projector
        a, b = np.asarray(op.forward(x)), np.asarray(op.adjoint(y))
        diffs[key] = (
            f"{np.abs(a - forward).max() / np.abs(forward).max():.0e}/"
            f"{np.abs(b - back).max() / np.abs(back).max():.0e}"
        )
    floor = ColumnTransformFloor(projector, 1)
    ours_iterates = richardson_lucy_iterates(projector, image, initial=volume, iterations=10**6)
    next(ours_iterates)  # warm-up (and A^T 1, computed once per reconstruction)
    keys = ("ours", "pruned", "otf") + (("convolve",) if not args.quick else ()) + ("floor",)
    times = {(key, n): [] for key in keys for n in args.threads}
    for repeat in range(args.repeats):
        for n in args.threads:
            torch.set_num_threads(n)
            for loop in (*loops.values(), floor):
                loop.workers = n
            for key in keys:
                if key == "convolve" and repeat >= 2:  # slow and far behind: two samples are enough
                    continue
                if key == "ours":
                    step = lambda: next(ours_iterates)  # noqa: E731
                elif key == "floor":
                    step = floor.iteration
                else:
                    step = lambda op=loops[key]: numpy_rl_iteration(op, x, y, sensitivity)  # noqa: E731
                t0 = time.perf_counter()
                step()
                times[(key, n)].append(time.perf_counter() - t0)
    labels = {
        "ours": ("ours: richardson_lucy_iterates, ShiftInvariantProjector", "reference"),
        "pruned": ("(i) pruned scipy.fft loop, cached OTFs (baseline)", diffs["pruned"]),
        "otf": ("(ii) unpruned cached-OTF scipy.fft rfft2 loop", diffs["otf"]),
        "convolve": ("(iii) per-depth scipy.signal.fftconvolve loop", diffs["convolve"]),
        "floor": ("(floor) column transforms alone, 2 per depth (scipy.fft)", "-"),
    }
    print(
        f"{'one RL iteration':<58} {'threads':>7} {'time (s)':>9} {'/ ours':>7} {'A x / A^T y rel. diff':>21}"
    )
    for n in args.threads:
        ours = statistics.median(times[("ours", n)])
        for key in keys:
            seconds = statistics.median(times[(key, n)])
            label, diff = labels[key]
            print(f"{label:<58} {n:>7} {seconds:>9.3f} {seconds / ours:>7.2f} {diff:>21}")
        ratio = statistics.median(times[("pruned", n)]) / ours
        print(
            f"goal, {n} thread(s): ours >= 2x faster than the pruned scipy loop (i): "
            f"{'met' if ratio >= 2 else 'NOT met'} ({ratio:.2f}x); bound with these transforms: "
            f"(i) / (floor) = {statistics.median(times[('pruned', n)]) / statistics.median(times[('floor', n)]):.2f}x"
        )
    if torch.cuda.is_available():
        section_cuda(stack, setup, image, volume)


def section_cuda(stack, setup, image, volume) -> None:
    from lfm_studio.engine.operators import ShiftInvariantProjector

    projector = ShiftInvariantProjector(stack.data.cuda(), setup.volume_shape[1:])
    on_cpu = setup.projector.forward(volume)  # the same operator on the CPU: the CUDA path must agree
    on_gpu = projector.forward(volume.cuda()).cpu()
    print(
        f"(c) CUDA A x against the CPU projector: max relative difference "
        f"{float((on_gpu - on_cpu).abs().max() / on_cpu.abs().max()):.1e} (float32)"
    )
    iterates = richardson_lucy_iterates(projector, image.cuda(), initial=volume.cuda(), iterations=10**6)
    for _ in range(3):
        next(iterates)
    samples = []
    for _ in range(10):
        torch.cuda.synchronize()
        t0 = time.perf_counter()
        next(iterates)
        torch.cuda.synchronize()
        samples.append(time.perf_counter() - t0)
    print(
        f"(c) CUDA {torch.cuda.get_device_name()}: one RL iteration "
        f"{1e3 * statistics.median(samples):.1f} ms (median of 10; goal <= 20 ms on an H100)"
    )


def section_time_to_quality(args) -> None:
    pixels = 256 if args.quick else 512
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        stack = simulate_psf(_design("flfm_guo2019", pixels, (-40.0, 40.0), 9))
    setup = imaging_setup(stack)
    projector = setup.projector
    truth = beads(setup.volume_shape, count=6, voxel_size=setup.voxel_size, seed=2, intensity=1000.0).data
    image = projector.forward(truth).clamp_min(0.0)
    if args.photons is not None:  # Poisson counts, args.photons at the brightest pixel (seeded)
        image = torch.poisson(image / image.max() * args.photons, generator=torch.Generator().manual_seed(1))

    def psnr(estimate: torch.Tensor) -> float:
        mse = float(((estimate.double() - truth.double()) ** 2).mean())
        return 10 * float(np.log10(float(truth.max()) ** 2 / mse))

    def ncc(estimate: torch.Tensor) -> float:
        t, e = truth.double().flatten(), estimate.double().flatten()
        t, e = t - t.mean(), e - e.mean()
        norm = float(t.norm() * e.norm())
        return float((t * e).sum()) / norm if norm > 0 else 0.0

    score = ncc if args.metric == "ncc" else psnr

    horizons = (30,) if args.quick else (30, 100)  # targets: PSNR after this many plain iterations

    warm_up = richardson_lucy_iterates(projector, image, iterations=5)
    for _ in warm_up:  # allocator and FFT plans: the first iterations in a process run slower
        pass
    methods = {
        "plain RL": {},
        "Biggs-Andrews": {"acceleration": "biggs-andrews"},
        "geometric (Biggs-Andrews on log x)": {"acceleration": "geometric"},
        "Wiener-Butterworth (alpha 1)": {"backprojector": "wb"},
        "Wiener-Butterworth + Biggs-Andrews": {"backprojector": "wb", "acceleration": "biggs-andrews"},
        "Wiener-Butterworth + geometric": {"backprojector": "wb", "acceleration": "geometric"},
        "WB alpha 0.7 + geometric (rl-accelerated until 2026-11)": {
            "backprojector": "wb0.7",
            "acceleration": "geometric",
        },
        "accelerated_rl_options (geometric, matched A^T)": {"recommended": True},
    }
    runs = {}
    for label, options in methods.items():
        t0 = time.perf_counter()
        if options.get("backprojector") in ("wb", "wb0.7"):
            alpha = 0.7 if options["backprojector"] == "wb0.7" else 1.0
            options = {**options, "backprojector": wiener_butterworth_backprojector(projector, alpha=alpha)}
        if options.pop("recommended", False):
            options = accelerated_rl_options(projector)
        # Set-up (checks, A^T 1, the back projector's flux) runs here, when the iterator is made.
        iterates = richardson_lucy_iterates(projector, image, iterations=max(horizons), **options)
        build = time.perf_counter() - t0
        runs[label] = {"build": build, "iterates": iterates, "samples": [], "psnr": []}
    # All methods advance in lockstep, one iteration each in turn, so they share the machine's load.
    for _ in range(max(horizons)):
        for run in runs.values():
            t0 = time.perf_counter()
            it = next(run["iterates"])
            run["samples"].append(time.perf_counter() - t0)
            run["psnr"].append(score(it.estimate))  # not timed
    targets = {h: runs["plain RL"]["psnr"][h - 1] for h in horizons}
    rows = []
    for label, run in runs.items():
        per_iteration = statistics.median(run["samples"][1:])  # the first one also computes A^T 1
        reached = {}
        for h in horizons:
            count = next((k + 1 for k, v in enumerate(run["psnr"]) if v >= targets[h]), None)
            if count is not None:
                reached[h] = (count, run["build"] + count * per_iteration)
        rows.append((label, reached, run["build"], per_iteration))
    plain = rows[0][1]
    time_formula = "time = set-up + iterations x median s/it"
    print(
        f"\n# (b) flfm_guo2019: camera {pixels} x {pixels}, volume {tuple(setup.volume_shape)}, 6 beads, "
        f"{'noise-free' if args.photons is None else f'{args.photons:g} photons at the brightest pixel'}, "
        f"{torch.get_num_threads()} thread(s); targets: {args.metric.upper()} of plain RL after "
        + ", ".join(f"{h} iterations ({targets[h]:.4g})" for h in horizons)
    )
    header = "".join(f" {'its':>5} {'time (s)':>9} {'/ plain':>8}" for _ in horizons)
    print(f"{'method':<56} {'set-up (s)':>10} {'s/it':>7}{header}   (per target, left to right)")
    ratios = []
    for label, reached, build, per_iteration in rows:
        cells = f" {build:>10.3f} {per_iteration:>7.4f}"
        for h in horizons:
            if h in reached:
                count, seconds = reached[h]
                ratio = seconds / plain[h][1]
                cells += f" {count:>5} {seconds:>9.3f} {ratio:>8.2f}"
                if label != "plain RL" and h == horizons[-1]:
                    ratios.append(ratio)
            else:
                cells += f" {'-':>5} {'not reached':>9} {'':>8}"
        print(f"{label:<56}{cells}")
    best = min(ratios) if ratios else float("nan")
    print(time_formula)
    goal = 1 / 4 if horizons[-1] == 100 else 1 / 3
    verdict = "met" if best <= goal else "NOT met"
    print(
        f"goal ({horizons[-1]}-iteration target): accelerated <= 1/{round(1 / goal)} of plain RL's time: "
        f"{verdict} (best {best:.2f})"
    )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="small sizes, under a minute")
    parser.add_argument(
        "--threads",
        type=int,
        nargs="+",
        default=[1],
        help="torch threads and scipy FFT workers; several values are interleaved in (a), (b) uses the "
        "first (default 1: with other jobs on this 2-core machine, 2 threads thrash without "
        "OMP_WAIT_POLICY=PASSIVE, which importing lfm_studio sets)",
    )
    parser.add_argument("--pixels", type=int, default=2048, help="(a) camera side in pixels")
    parser.add_argument("--depths", type=int, default=64)
    parser.add_argument(
        "--photons", type=float, default=None, help="(b) Poisson noise: photons at the brightest pixel"
    )
    parser.add_argument(
        "--metric", choices=("psnr", "ncc"), default="psnr", help="(b) quality score of the targets"
    )
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--skip-iteration", action="store_true")
    parser.add_argument(
        "--cuda-only", action="store_true", help="(a) time only the CUDA iteration (scripts/gpu_check.sh)"
    )
    parser.add_argument("--skip-quality", action="store_true")
    args = parser.parse_args()
    keep_freed_memory()  # as the CLI does
    print(describe_threads())
    if not args.skip_iteration:
        section_iteration(args)
    if not args.skip_quality:
        torch.set_num_threads(args.threads[0])
        section_time_to_quality(args)


if __name__ == "__main__":
    main()
