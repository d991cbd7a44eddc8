"""Runtime and accuracy of the free-space propagators: one table.

    python benchmarks/propagation.py [--sizes 512 1024 2048 4096] [--quick] [--repeats 3]

For each size N, propagator, dtype (complex64/complex128) and kernel state (cached:
the transfer function comes from a kernel cache; uncached: built on every call), it
prints the median time of one propagation over ``--repeats`` runs (at most 2 at
N >= 4096, where one padded 8192^2 run takes seconds, and with ``--quick``) taken in interleaved order (every
configuration once per round, the order rotated between rounds, because this CPU is
shared; when the cached kernels of all configurations would exceed 3 GiB, as at 4096,
the rounds interleave the configurations of one method at a time), the ratio to the
uncached complex128 ASM of the same size, and the relative L2 error of the field
against a reference. Cached configurations get one untimed warm-up run (it fills the
cache); FFT plans are warm after the first run of a size.

Test field and distance (physically meaningful, and where the methods differ): a
Gaussian beam of waist w0 = 4.5 dx at 488 nm on an N x N grid of dx = lambda / 2
(Nyquist at 90 degrees; divergence lambda / (pi w0) = 8 degrees), propagated to the
padded critical distance z = 2 N dx^2 / lambda (padding 2). There the beam is still
inside the window, the band limit is active (45 degrees), Fresnel's paraxial phase
error is visible, and the Fresnel impulse response lands on spacing lambda z / (2 N dx)
= dx, so every method is compared on the same samples (IR: the central N x N).

Reference: the float64 band-limited ASM on a 2x finer grid (2N samples of dx / 2, the
same window, padding 2), evaluated at the common (coarse) samples. The beam's spectrum
on the fine grid is the analytic pi w0^2 exp(-pi^2 w0^2 f^2) (the sampled beam's DFT
equals it to exp(-pi^2 w0^2 / dx_fine^2) ~ 1e-87), and decimating to the coarse samples
is done in the frequency domain by folding the fine spectrum modulo 1 / dx (exact for
DFTs), so the reference costs one FFT of the padded coarse size. Folded terms whose
Gaussian bound is below 1e-30 are skipped (they are, for w0 = 4.5 dx).
Timings exclude the sampling checks (``check_sampling=False``); their cost is printed
below the table.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
import warnings

import torch

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from lfm_studio.engine import fft
from lfm_studio.engine.errors import SamplingWarning
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.kernel_cache import KernelCache
from lfm_studio.engine.optics.padding import crop_to
from lfm_studio.engine.optics.propagation import propagate
from lfm_studio.engine.optics.sampling import bandlimit_frequency
from lfm_studio.engine.optics.sources import gaussian_beam

WAVELENGTH = 488e-9
METHODS = ("asm", "bandlimited_asm", "fresnel_tf", "fresnel_ir")
DTYPES = (torch.complex64, torch.complex128)
BASELINE = ("asm", torch.complex128, "uncached")


def setup(n: int) -> tuple[Grid, float, float]:
    """Grid, waist and distance (metres) of the test case for size ``n``."""
    dx = WAVELENGTH / 2
    return Grid(n, dx), 4.5 * dx, 2 * n * dx * dx / WAVELENGTH


def reference(grid: Grid, waist: float, z: float) -> torch.Tensor:
    """Float64 band-limited ASM on the 2x finer grid, at the coarse samples (module docstring)."""
    n, dx = grid.nx, grid.dx
    m = 2 * n  # padded coarse size; the fine padded grid has 2m samples of dx / 2, same window
    window = m * dx
    fine = Grid(2 * m, dx / 2)
    limit_y, limit_x = bandlimit_frequency(fine, WAVELENGTH, z)
    k = torch.arange(m, dtype=torch.float64) - m // 2
    f0 = k / window  # centred coarse frequencies, [-1 / (2 dx), 1 / (2 dx))
    folded = torch.zeros((m, m), dtype=torch.complex128)
    inv_l = 1.0 / WAVELENGTH
    for ay in (-1, 0, 1):
        for ax in (-1, 0, 1):
            fy, fx = f0 + ay / dx, f0 + ax / dx
            in_y, in_x = (fy >= -1 / dx) & (fy < 1 / dx), (fx >= -1 / dx) & (fx < 1 / dx)
            nearest = (
                min(float(fy[in_y].abs().min()), float(fx[in_x].abs().min()))
                if in_y.any() and in_x.any()
                else 1e9
            )
            if (ay or ax) and math.exp(-((math.pi * waist * nearest) ** 2)) < 1e-30:
                continue  # the Gaussian is below 1e-30 of its peak on this whole folded band
            f2 = fy[:, None] ** 2 + fx[None, :] ** 2
            keep = (
                (in_y & (fy.abs() <= limit_y))[:, None]
                & (in_x & (fx.abs() <= limit_x))[None, :]
                & (f2 < inv_l**2)
            )
            spectrum = math.pi * waist**2 * torch.exp(-((math.pi * waist) ** 2) * f2)
            phase = (
                -2 * math.pi * z * f2 / (inv_l + torch.sqrt(torch.clamp(inv_l**2 - f2, min=0.0)))
                + 2 * math.pi * z * inv_l
            )
            folded += torch.polar(spectrum * keep, phase)
    field = fft.centered_ifft2(folded) * (m * m) / (window * window)
    return crop_to(field, (n, n))


def run_once(field, z, method, cache):
    return propagate(field, z, method=method, cache=cache, check_sampling=False)


def output_window(out, n: int) -> torch.Tensor:
    return crop_to(out.data, (n, n)).to(torch.complex128)


CACHE_BUDGET = 3 << 30  # bytes of cached kernels the benchmark allows itself


def kernel_bytes(n: int, method: str, dtype: torch.dtype) -> int:
    """Bytes of the cached kernel of one configuration (padded size 2n)."""
    item = torch.empty((), dtype=dtype).element_size()
    return item * (4 * n * n + (n * n if method == "fresnel_ir" else 0))


def bench_size(n: int, repeats: int, rows: list, notes: list) -> None:
    if n >= 4096:  # one padded 8192^2 propagation takes seconds here: keep the full run near 5 minutes
        repeats = min(repeats, 2)
    grid, waist, z = setup(n)
    ref = reference(grid, waist, z)
    source = gaussian_beam(grid, WAVELENGTH, waist, dtype=torch.complex128)
    fields = {d: source.to(dtype=d) for d in DTYPES}
    configs = [(m, d, c) for m in METHODS for d in DTYPES for c in ("uncached", "cached")]
    if sum(kernel_bytes(n, m, d) for m, d, c in configs if c == "cached") <= CACHE_BUDGET:
        groups = [configs]  # every configuration once per round
    else:  # the cached kernels do not fit together: interleave within each method
        groups = [[c for c in configs if c[0] == m] for m in METHODS]
        notes.append(
            f"N = {n}: the cached kernels of all configurations exceed {CACHE_BUDGET >> 30} GiB, so runs are "
            "interleaved within each method; ratios across methods compare different minutes."
        )
    cache = KernelCache(budget_bytes=CACHE_BUDGET)
    errors, times = {}, {c: [] for c in configs}
    for group in groups:
        for method, dtype, state in group:  # warm-up of the cached ones: fills the cache, measures the error
            if state == "cached":
                out = run_once(fields[dtype], z, method, cache)
                errors[(method, dtype, state)] = float((output_window(out, n) - ref).norm() / ref.norm())
                del out
        for r in range(repeats):
            shift = (r * 3) % len(group)
            for config in group[shift:] + group[:shift]:
                method, dtype, state = config
                start = time.perf_counter()
                out = run_once(fields[dtype], z, method, cache if state == "cached" else False)
                times[config].append(time.perf_counter() - start)
                if config not in errors:
                    errors[config] = float((output_window(out, n) - ref).norm() / ref.norm())
                del out
        cache.clear()
    base = statistics.median(times[BASELINE])
    for c in configs:
        t = statistics.median(times[c])
        rows.append(
            (n, c[0], str(c[1]).replace("torch.", ""), c[2], len(times[c]), t * 1e3, t / base, errors[c])
        )


def check_overhead(n: int) -> tuple[float, float]:
    """Median time (ms) of a cached complex64 band-limited ASM with and without sampling checks."""
    grid, waist, z = setup(n)
    field = gaussian_beam(grid, WAVELENGTH, waist, dtype=torch.complex64)
    cache = KernelCache()
    timings = {False: [], True: []}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SamplingWarning)
        propagate(field, z, method="bandlimited_asm", cache=cache)
        for _ in range(3):
            for checks in (False, True):
                start = time.perf_counter()
                propagate(field, z, method="bandlimited_asm", cache=cache, check_sampling=checks)
                timings[checks].append(time.perf_counter() - start)
    return statistics.median(timings[False]) * 1e3, statistics.median(timings[True]) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[512, 1024, 2048, 4096])
    parser.add_argument("--quick", action="store_true", help="only 512 and 1024, 2 runs each (under 30 s)")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    sizes = [512, 1024] if args.quick else args.sizes
    repeats = min(args.repeats, 2) if args.quick else args.repeats
    started = time.perf_counter()
    load = os.getloadavg()[0]
    rows: list = []
    notes: list = []
    for n in sizes:
        bench_size(n, repeats, rows, notes)
    overhead_size = min(sizes[-1], 2048)
    overhead = check_overhead(overhead_size)
    print(
        f"Free-space propagation, torch {torch.__version__}, {torch.get_num_threads()} threads, "
        f"load average {load:.1f} -> {os.getloadavg()[0]:.1f}. Gaussian w0 = 4.5 dx, lambda = 488 nm, "
        "dx = lambda/2, z = 2 N dx^2/lambda, padding 2; time = median of the interleaved runs; "
        "ratio = time / uncached complex128 asm at the same N; "
        "error = relative L2 vs float64 band-limited ASM on a 2x finer grid."
    )
    header = (
        f"{'N':>5} {'method':<16} {'dtype':<10} {'kernel':<9} {'runs':>4} {'time [ms]':>10} {'ratio':>7} "
        f"{'rel. L2 error':>14}"
    )
    print(header)
    print("-" * len(header))
    for n, method, dtype, state, runs, ms, ratio, error in rows:
        print(
            f"{n:>5} {method:<16} {dtype:<10} {state:<9} {runs:>4} {ms:>10.1f} {ratio:>7.2f} {error:>14.2e}"
        )
    for note in notes:
        print(note)
    print(
        f"Sampling checks (check_sampling=True, the default) on cached complex64 bandlimited_asm at "
        f"N = {overhead_size}: {overhead[1]:.1f} ms vs {overhead[0]:.1f} ms without. "
        f"Total run {time.perf_counter() - started:.0f} s."
    )


if __name__ == "__main__":
    main()
