"""Reconstruction speed: one 3D Richardson-Lucy iteration against scipy loops, and time to quality.

    python benchmarks/reconstruct.py [--quick] [--threads 2] [--depths 64] [--repeats 3]

(a) XLFM preset (xlfm_cong2017), 2048 x 2048 camera, 64 depths, the design's field of view:
    one RL iteration (forward projection, ratio, back projection, update) of
    ``lfm_studio.engine.reconstruct`` against two baselines written here and run in the same
    process on the same data, both with ``--threads`` FFT workers:
    (i)  a cached-OTF ``scipy.fft`` loop: rfft2/irfft2 per depth on the same zero-padded FFT
         window, OTFs precomputed (the projector's own, shared);
    (ii) a per-depth ``scipy.signal.fftconvolve`` loop (full convolution, cropped; valid
         correlation for the back projection), which recomputes every FFT.
    Timings alternate between methods (other jobs share this machine); the table gives the
    median over ``--repeats`` and the ratios of those medians.
    Goals: ours <= 1.2x (i) and >= 3x faster than (ii). The baselines' A x and A^T y are
    checked against the engine projector's (max relative difference).
(b) Time to reach the PSNR that 30 (and 100) plain RL iterations reach, on a smaller problem
    (FLFM preset, 512 x 512 camera, 9 depths over +-40 um, 6 beads, noise-free): plain,
    Biggs-Andrews, Wiener-Butterworth back projector and both, advanced in lockstep (one
    iteration each in turn, same load); time = back-projector build + iterations x the
    method's median iteration time. Goal: <= 1/3 of plain RL's time for the 30-iteration target.
(c) With CUDA: the (a) iteration on the GPU (goal <= 20 ms on an H100).

``--quick`` (under a minute): (a) with 4 depths, (b) with a 256 px camera and the 30-iteration target.
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings

import numpy as np
import scipy.fft
import scipy.signal
import torch

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
    pixels, depths = 2048, (4 if args.quick else args.depths)
    design = _design("xlfm_cong2017", pixels, (-200.0, 200.0), depths)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        stack = simulate_psf(design)
    t_psf = time.perf_counter() - t0
    setup = imaging_setup(stack)
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
        f"volume {tuple(setup.volume_shape)}, "
        f"FFT window {tuple(projector.fft_shape)}, float32, {args.threads} thread(s); PSF stack {t_psf:.1f} s"
    )

    scipy_loop = ScipyOTFLoop(projector, args.threads)
    convolve_loop = ScipyFFTConvolveLoop(stack.data.numpy(), projector, args.threads)
    y, x = image.numpy(), volume.numpy()
    sensitivity = scipy_loop.adjoint(np.ones_like(y))

    # Same operators: A x and A^T y of each implementation against the engine's projector.
    forward, back = projector.forward(volume).numpy(), projector.adjoint(image).numpy()

    def difference(op) -> str:
        a = np.asarray(op.forward(x if isinstance(op, (ScipyOTFLoop, ScipyFFTConvolveLoop)) else volume))
        b = np.asarray(op.adjoint(y if isinstance(op, (ScipyOTFLoop, ScipyFFTConvolveLoop)) else image))
        da, db = (
            np.abs(a - forward).max() / np.abs(forward).max(),
            np.abs(b - back).max() / np.abs(back).max(),
        )
        return f"{da:.0e}/{db:.0e}"

    diffs = {"scipy": difference(scipy_loop)}
    t0 = time.perf_counter()
    numpy_rl_iteration(convolve_loop, x, y, sensitivity)
    t_convolve = [time.perf_counter() - t0]
    diffs["convolve"] = difference(convolve_loop)

    ours_iterates = richardson_lucy_iterates(projector, image, initial=volume, iterations=10**6)
    next(ours_iterates)  # warm-up (and A^T 1, computed once per reconstruction)
    times = {"ours": [], "scipy": []}
    for _ in range(args.repeats):
        for key, step in (
            ("ours", lambda: next(ours_iterates)),
            ("scipy", lambda: numpy_rl_iteration(scipy_loop, x, y, sensitivity)),
        ):
            t0 = time.perf_counter()
            step()
            times[key].append(time.perf_counter() - t0)
    if args.repeats > 1 and not args.quick:
        t0 = time.perf_counter()
        numpy_rl_iteration(convolve_loop, x, y, sensitivity)
        t_convolve.append(time.perf_counter() - t0)
    ours, ref = (statistics.median(times[k]) for k in ("ours", "scipy"))
    conv = statistics.median(t_convolve)
    print(f"{'one RL iteration':<52} {'time (s)':>9} {'/ ours':>7} {'A x / A^T y rel. diff':>21}")
    for label, seconds, diff in (
        ("ours: richardson_lucy_iterates, ShiftInvariantProjector", ours, "reference"),
        ("(i) cached-OTF scipy.fft loop", ref, diffs["scipy"]),
        ("(ii) per-depth scipy.signal.fftconvolve loop", conv, diffs["convolve"]),
    ):
        print(f"{label:<52} {seconds:>9.3f} {seconds / ours:>7.2f} {diff:>21}")
    print(
        f"goals: ours <= 1.2x (i): {'met' if ours <= 1.2 * ref else 'NOT met'} ({ours / ref:.2f}x); >= 3x faster than (ii): {'met' if conv >= 3 * ours else 'NOT met'} "
        f"({conv / ours:.1f}x). Samples: ours {[round(t, 3) for t in times['ours']]}, "
        f"(i) {[round(t, 3) for t in times['scipy']]}, "
        f"(ii) {[round(t, 2) for t in t_convolve]}"
    )
    if torch.cuda.is_available():
        section_cuda(stack, setup, image, volume)


def section_cuda(stack, setup, image, volume) -> None:
    from lfm_studio.engine.operators import ShiftInvariantProjector

    projector = ShiftInvariantProjector(stack.data.cuda(), setup.volume_shape[1:])
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

    def psnr(estimate: torch.Tensor) -> float:
        mse = float(((estimate.double() - truth.double()) ** 2).mean())
        return 10 * float(np.log10(float(truth.max()) ** 2 / mse))

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
        "accelerated_rl_options (WB alpha 0.7 + geometric)": {"recommended": True},
    }
    runs = {}
    for label, options in methods.items():
        t0 = time.perf_counter()
        if options.get("backprojector") == "wb":
            options = {**options, "backprojector": wiener_butterworth_backprojector(projector)}
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
            run["psnr"].append(psnr(it.estimate))  # not timed
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
        f"noise-free, {args.threads} thread(s); targets: PSNR of plain RL after "
        + ", ".join(f"{h} iterations ({targets[h]:.2f} dB)" for h in horizons)
    )
    header = "".join(f" {'its':>5} {'time (s)':>9} {'/ plain':>8}" for _ in horizons)
    print(f"{'method':<50} {'set-up (s)':>10} {'s/it':>7}{header}   (per target, left to right)")
    ratios = []
    for label, reached, build, per_iteration in rows:
        cells = f" {build:>10.3f} {per_iteration:>7.4f}"
        for h in horizons:
            if h in reached:
                count, seconds = reached[h]
                ratio = seconds / plain[h][1]
                cells += f" {count:>5} {seconds:>9.3f} {ratio:>8.2f}"
                if label != "plain RL" and h == 30:
                    ratios.append(ratio)
            else:
                cells += f" {'-':>5} {'not reached':>9} {'':>8}"
        print(f"{label:<50}{cells}")
    best = min(ratios) if ratios else float("nan")
    print(time_formula)
    verdict = "met" if best <= 1 / 3 else "NOT met"
    print(f"goal (30-iteration target): accelerated <= 1/3 of plain RL's time: {verdict} (best {best:.2f})")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="small sizes, under a minute")
    parser.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch threads and scipy FFT workers (default 1: with other jobs on this 2-core machine, torch "
        "with 2 threads thrashed, 3-11 s per iteration instead of 5)",
    )
    parser.add_argument("--depths", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--skip-iteration", action="store_true")
    parser.add_argument("--skip-quality", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    if not args.skip_iteration:
        section_iteration(args)
    if not args.skip_quality:
        section_time_to_quality(args)


if __name__ == "__main__":
    main()
