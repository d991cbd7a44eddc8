"""Per-lenslet PSF kernel of the Fourier LFM: ours against a whole-patch baseline in the same run.

    python benchmarks/lenslet_psf.py [--preset xlfm_cong2017] [--pixels 2048] [--depths 16]
        [--threads 1] [--repeats 3]

For every lenslet of the preset (its accuracy knobs: oversampling, pixel integration, dtype,
depth chunk) the power patch behind it at ``--depths`` depths over +-200 um is computed twice:

- **ours**, :func:`lenslet_psf`: the input field only on the box where the lenslet aperture is
  non-zero, a row then a column transform zero-padded to the patch, the pixel box integral folded
  from the half spectrum;
- **baseline** (written here): the input field on every patch sample, a centred ``fft2`` of the
  whole patch, and the box filter as a 2-D product on the full spectrum read at the pixel centres
  (the plain formula; ``"midpoint"`` sums the sub-sample blocks).

Both compute the same depth-independent terms per lenslet (:func:`prepare_lenslet`, timed in both).
Prints per-lenslet-set seconds (medians, the two timed alternately), the ratio baseline / ours
and the largest difference relative to the patch's peak.
"""

from __future__ import annotations

import lfm_studio  # noqa: F401  # isort: skip  (first: sets OMP_WAIT_POLICY before torch loads, engine/threads.py)
import argparse
import math
import statistics
import time
import warnings

import torch

from lfm_studio.engine.design import load_preset
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.dtypes import complex_dtype
from lfm_studio.engine.systems.fourier_lenslet import lenslet_psf, prepare_lenslet
from lfm_studio.engine.systems.fourier_psf import resolve_method
from lfm_studio.engine.systems.from_design import fourier_accuracy_of, fourier_system_of
from lfm_studio.engine.threads import describe_threads, torch_threads


def baseline_power(prepared, depths: torch.Tensor, oversampling: int, integration: str) -> torch.Tensor:
    """Power per pixel ``(Z, N/s, N/s)`` the plain way: whole-patch phasors, ``fft2``, 2-D box filter."""
    phase = depths[:, None, None] * prepared.defocus + prepared.static_phase + prepared._checker_phase
    if prepared.dtype == torch.float32:
        phase = torch.remainder(phase, 2.0 * math.pi).to(torch.float32)
    spectrum = torch.fft.fft2(torch.polar(prepared.amplitude.expand_as(phase), phase))
    power = spectrum.real**2 + spectrum.imag**2
    s, n = oversampling, power.shape[-1]
    if integration == "midpoint":
        return power.reshape(-1, n // s, s, n // s, s).sum((-3, -1))
    f = torch.fft.fftfreq(n, d=1.0 / s, dtype=torch.float64)  # cycles per pixel
    transfer = (s * torch.sinc(f) * torch.exp(2j * math.pi * f * (s - 1) / (2.0 * s))).to(
        complex_dtype(power.dtype)
    )
    filtered = torch.fft.ifft2(torch.fft.fft2(power) * transfer[:, None] * transfer[None, :]).real
    return filtered[..., ::s, ::s].clamp_min(0.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="xlfm_cong2017")
    parser.add_argument("--pixels", type=int, default=2048, help="camera pixels per side")
    parser.add_argument("--depths", type=int, default=16)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    torch_threads(args.threads)
    design = load_preset(args.preset)
    camera = type(design.camera)(**{**design.camera.model_dump(), "pixel_count": (args.pixels, args.pixels)})
    design = design.updated(camera=camera)
    system, acc = fourier_system_of(design), fourier_accuracy_of(design)
    depths = tuple(torch.linspace(-200e-6, 200e-6, args.depths, dtype=torch.float64).tolist())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DesignWarning)
        method, windows = resolve_method(system, depths, acc)
    z = torch.tensor(depths, dtype=torch.float64)
    s, integration = acc.oversampling, acc.pixel_integration
    lenslets = list(zip(system.mla.lenslets, windows, strict=True))
    print(
        f"# {args.preset}: camera {args.pixels}^2, {len(lenslets)} lenslets ({method}), {args.depths} depths, "
        f"oversampling {s}, {integration} pixel integration, {acc.dtype}; {describe_threads()}"
    )

    def prepared():
        return [
            prepare_lenslet(system, lens, window, z, s, acc.model, acc.antialias, acc.dtype)
            for lens, window in lenslets
        ]

    def ours():
        return [
            lenslet_psf(
                system, lens, window, z, oversampling=s, model=acc.model, antialias=acc.antialias, dtype=acc.dtype,
                depth_chunk=acc.depth_chunk, pixel_integration=integration,
            )
            for lens, window in lenslets
        ]  # fmt: skip

    def baseline():
        return [
            torch.cat([baseline_power(p, chunk, s, integration) for chunk in z.split(acc.depth_chunk)])
            for p in prepared()
        ]

    worst = max(float((a - b).abs().max() / b.abs().max()) for a, b in zip(ours(), baseline(), strict=True))
    times: dict[str, list[float]] = {"ours": [], "baseline": []}
    for _ in range(args.repeats):
        for name, run in (("baseline", baseline), ("ours", ours)):
            start = time.perf_counter()
            run()
            times[name].append(time.perf_counter() - start)
    base, new = statistics.median(times["baseline"]), statistics.median(times["ours"])
    (r0, r1), (c0, c1) = prepared()[0]._support
    print(f"first lenslet: patch {windows[0].samples}^2 samples, aperture box {r1 - r0} x {c1 - c0}")
    print(f"baseline (whole patch) {base:.3f} s, ours {new:.3f} s, baseline / ours {base / new:.2f}")
    print(f"largest difference / patch peak: {worst:.1e}")


if __name__ == "__main__":
    main()
