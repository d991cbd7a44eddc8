"""Reconstructed two-point resolution: two equal emitters imaged through a design and
reconstructed with plain Richardson-Lucy (``lfm-studio resolution``).

For each depth ``z`` of interest a volume grid is built around it: the design's lateral
voxel (:func:`~lfm_studio.engine.simulation.imaging_setup`: sensor pixel / M_T / k for a
Fourier LFM with ``accuracy.volume_oversampling`` k, pitch / (M voxels_per_lenslet) for a
conventional one) and ``2 J + 1`` depths ``z + (j - J) dz``. Then, for separations of
``s`` voxels (lateral, along x through the centre of the grid) or depth steps (axial,
along z through the centre), two emitters of equal brightness are placed ``s``
apart, imaged (noise free, or Poisson shot noise for ``photons`` detected photons per
emitter), and reconstructed with plain RL from a flux-matched uniform start. The dip ratio
(:func:`~.two_point.dip_ratio`) is read on the reconstruction along the line through both
emitters, linearly interpolated between voxels; the reported resolution is the smallest
``s`` whose dip is below ``threshold`` (0.735, the Rayleigh-like dip), times the voxel,
found by growing ``s`` about 1.4x from 2 and bisecting the last bracket (a few RL runs).

**Grid floor**: emitters one voxel apart have no voxel between them, and a linear
interpolant has no interior minimum below its end values, so no dip below 1 can appear
under 2 voxels: the reported resolution is never below ``2 x voxel`` (``grid_floor``).
A finer grid (``voxels_per_lenslet``, ``volume_oversampling``, a smaller depth step)
lowers that floor.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch

from lfm_studio.engine.design import Design
from lfm_studio.engine.performance.two_point import RAYLEIGH_DIP, dip_ratio
from lfm_studio.engine.progress import CancelToken, checkpoint
from lfm_studio.engine.reconstruct.richardson_lucy import richardson_lucy
from lfm_studio.engine.simulation import ImagingSetup, imaging_setup, simulate_psf


@dataclass(frozen=True)
class DepthResolution:
    """The reconstructed two-point resolution at one depth (lengths in metres).

    Attributes
    ----------
    depth : float
        Depth of the emitter pair (the lateral pair; the axial pair starts half a separation above).
    lateral, axial : float or None
        Smallest resolved separation; None when none up to the largest tried resolves.
    lateral_dips, axial_dips : tuple of (separation in m, dip ratio)
        The separations tried and their dips.
    """

    depth: float
    lateral: float | None
    axial: float | None
    lateral_dips: tuple[tuple[float, float], ...]
    axial_dips: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class ResolutionReport:
    """Reconstructed two-point resolution of a design at several depths (SI units).

    Attributes
    ----------
    design_name, kind : of the design.
    lateral_voxel, axial_voxel : volume grid, m.
    photons : detected photons per emitter (None: noise free).
    iterations : plain RL iterations.
    threshold : dip ratio below which a pair counts as resolved.
    crop : camera pixels kept about the axis (None: the whole sensor).
    depths : one :class:`DepthResolution` per depth.
    """

    design_name: str
    kind: str
    lateral_voxel: float
    axial_voxel: float
    photons: float | None
    iterations: int
    threshold: float
    crop: int | None
    depths: tuple[DepthResolution, ...]

    @property
    def lateral_grid_floor(self) -> float:
        """Smallest lateral separation that can show a dip: 2 voxels, m."""
        return 2.0 * self.lateral_voxel

    @property
    def axial_grid_floor(self) -> float:
        """Smallest axial separation that can show a dip: 2 depth steps, m."""
        return 2.0 * self.axial_voxel

    def to_dict(self) -> dict:
        """JSON-ready dict, lengths in micrometres (``_um`` keys)."""

        def um(value: float | None) -> float | None:
            return None if value is None else value / 1e-6

        return {
            "schema": "lfm_studio.reconstructed_resolution",
            "schema_version": 1,
            "design_name": self.design_name,
            "kind": self.kind,
            "method": "plain Richardson-Lucy",
            "iterations": self.iterations,
            "photons_per_emitter": self.photons,
            "dip_threshold": self.threshold,
            "crop_pixels": self.crop,
            "lateral_voxel_um": um(self.lateral_voxel),
            "axial_voxel_um": um(self.axial_voxel),
            "lateral_grid_floor_um": um(self.lateral_grid_floor),
            "axial_grid_floor_um": um(self.axial_grid_floor),
            "depths": [
                {
                    "depth_um": um(d.depth),
                    "lateral_um": um(d.lateral),
                    "axial_um": um(d.axial),
                    "lateral_dips": [[um(s), dip] for s, dip in d.lateral_dips],
                    "axial_dips": [[um(s), dip] for s, dip in d.axial_dips],
                }
                for d in self.depths
            ],
        }


def linear_profile(values: torch.Tensor) -> Callable[[torch.Tensor], torch.Tensor]:
    """The piecewise-linear interpolant of ``values`` (index coordinates; constant beyond the ends)."""
    values = values.detach().to(torch.float64).cpu()
    last = values.numel() - 1

    def profile(t: torch.Tensor) -> torch.Tensor:
        t = t.clamp(0.0, float(last))
        i = t.floor().long().clamp(max=max(last - 1, 0))
        frac = t - i
        upper = values[(i + 1).clamp(max=last)]
        return values[i] * (1.0 - frac) + upper * frac

    return profile


def _pair_dip(
    setup: ImagingSetup,
    first: Sequence[int],
    second: Sequence[int],
    axis: int,
    *,
    photons: float | None,
    iterations: int,
    generator: torch.Generator,
) -> float:
    """Dip ratio of the RL reconstruction of two unit emitters at voxels ``first`` and ``second``
    (which differ along ``axis`` only), read along that axis."""
    projector = setup.projector
    dtype = projector.dtype
    volume = torch.zeros(setup.volume_shape, dtype=dtype)
    volume[tuple(first)] = 1.0
    volume[tuple(second)] = 1.0
    expected = projector.forward(volume).clamp_min(0.0).to(device="cpu", dtype=torch.float64)
    if photons is not None:  # Poisson shot noise, ``photons`` detected per emitter
        expected = expected * (2.0 * photons / float(expected.sum()))
        image = torch.poisson(expected, generator=generator)
    else:
        image = expected
    estimate = richardson_lucy(projector, image.to(dtype), iterations=iterations)
    line: list[int | slice] = [*first]
    line[axis] = slice(None)
    return dip_ratio(linear_profile(estimate[tuple(line)]), float(first[axis]), float(second[axis]))


def _scan(
    setup: ImagingSetup, depth: int, axis: int, largest: int, threshold: float, options: dict
) -> tuple[int | None, tuple[tuple[int, float], ...]]:
    """Smallest separation ``s`` in ``2 .. largest`` (voxels along ``axis``: 0 depth, 2 x) whose pair,
    centred on voxel ``(depth, centre, centre)``, dips below ``threshold``; and ``(s, dip)`` tried.

    Separations grow by about 1.4x until one resolves, then the integer bracket is bisected
    (assumes the dip falls with the separation, as it does for a single-peaked blur).
    ``s = 1`` is never tried: it cannot show a dip (grid floor).
    """
    _, vy, vx = setup.volume_shape
    centre = [depth, vy // 2, vx // 2]
    tried: dict[int, float] = {}

    def dip(s: int) -> float:
        if s not in tried:
            first = list(centre)
            first[axis] -= s // 2
            second = list(first)
            second[axis] += s
            tried[s] = _pair_dip(setup, first, second, axis, **options)
        return tried[s]

    largest = min(largest, setup.volume_shape[axis] - 1)
    lo, hi = 1, 2
    while hi <= largest and dip(hi) >= threshold:
        lo, hi = hi, max(hi + 1, round(hi * 1.4))
    if hi > largest:
        if lo < largest and dip(largest) < threshold:
            hi = largest
        else:
            return None, tuple(sorted(tried.items()))
    while hi - lo > 1:  # dip(lo) >= threshold (or lo = 1), dip(hi) < threshold
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if dip(mid) < threshold else (mid, hi)
    return hi, tuple(sorted(tried.items()))


def reconstructed_resolution(
    design: Design,
    depths: tuple[float, ...],
    *,
    depth_step: float | None = None,
    photons: float | None = None,
    iterations: int = 100,
    crop: int | None = 256,
    max_lateral: float = 10e-6,
    max_axial: float = 30e-6,
    threshold: float = RAYLEIGH_DIP,
    seed: int = 0,
    device: torch.device | str = "cpu",
    cancel: CancelToken = None,
) -> ResolutionReport:
    """Two-point resolution of ``design`` after plain RL at each of ``depths`` (metres).

    Parameters
    ----------
    depth_step : axial voxel in metres (default: the design's depth step).
    photons : detected photons per emitter (Poisson shot noise); None: noise free.
    iterations : plain RL iterations (>= 1).
    crop : camera pixels kept about the axis (see :func:`simulate_psf`); None: the whole sensor.
    max_lateral, max_axial : largest separations tried, m (at least 2 voxels / depth steps are tried).
    threshold : dip ratio below which the pair counts as resolved (default 0.735).
    seed : of the shot noise.
    """
    if not depths:
        raise ValueError("depths is empty. Fix: give at least one depth in metres, e.g. (0.0,).")
    if not (isinstance(iterations, int) and iterations >= 1):
        raise ValueError(f"iterations must be an integer >= 1; got {iterations!r}. Fix: e.g. 100.")
    for name, value in (("max_lateral", max_lateral), ("max_axial", max_axial)):
        if not (value > 0 and math.isfinite(value)):
            raise ValueError(
                f"{name} must be > 0 m (largest separation tried); got {value!r}. Fix: e.g. 2e-5."
            )
    if photons is not None and not photons > 0:
        raise ValueError(f"photons must be > 0 (detected photons per emitter) or None; got {photons!r}.")
    if not 0.0 < threshold < 1.0:
        raise ValueError(f"threshold must be in (0, 1); got {threshold!r}. Fix: 0.735 (Rayleigh-like).")
    dz = design.depths.depth_step_um * 1e-6 if depth_step is None else depth_step
    if not (dz > 0 and math.isfinite(dz)):
        raise ValueError(f"depth_step must be > 0 m; got {dz!r}. Fix: e.g. 2e-6.")
    generator = torch.Generator().manual_seed(seed)
    axial_steps = max(2, math.ceil(max_axial / dz - 1e-9))
    half = axial_steps // 2 + 1  # depths on each side: the axial pair is centred on z
    results: list[DepthResolution] = []
    voxel = math.nan  # set at the first depth (depths is not empty)
    for index, z in enumerate(depths):
        checkpoint(cancel, None, index, len(depths), f"depth {index + 1}/{len(depths)}")
        grid = tuple(z + (j - half) * dz for j in range(2 * half + 1))
        stack = simulate_psf(design, depths=grid, device=device, crop=crop)
        if not bool(stack.data.sum() > 0):
            raise ValueError(
                f"no light reaches the {'whole sensor' if crop is None else f'central {crop} x {crop} pixel crop'} "
                f"from depths {grid[0] / 1e-6:.4g} .. {grid[-1] / 1e-6:.4g} um. Fix: a larger crop "
                "(--crop, 0 = the whole sensor) that holds some of the lenslets' images."
            )
        lateral_steps = max(2, math.ceil(max_lateral / stack.object_pixel_size - 1e-9))
        setup = imaging_setup(stack, field_of_view=(2 * lateral_steps + 9) * stack.object_pixel_size)
        voxel = setup.voxel_size[1]
        options = dict(photons=photons, iterations=iterations, generator=generator)
        lateral, lateral_dips = _scan(
            setup, half, 2, math.ceil(max_lateral / voxel - 1e-9), threshold, options
        )
        axial, axial_dips = _scan(setup, half, 0, axial_steps, threshold, options)
        results.append(
            DepthResolution(
                z,
                None if lateral is None else lateral * voxel,
                None if axial is None else axial * dz,
                tuple((s * voxel, d) for s, d in lateral_dips),
                tuple((s * dz, d) for s, d in axial_dips),
            )
        )
    return ResolutionReport(
        design.name,
        design.kind,
        float(voxel),
        float(dz),
        photons,
        iterations,
        threshold,
        crop,
        tuple(results),
    )
