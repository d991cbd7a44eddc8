"""Fourier-LFM PSF stack (thesis eq. 3.23): per-lenslet small grids, or the full sensor field.

``per_lenslet`` (default when the lenslets' light footprints do not overlap on the
sensor): each lenslet on its own ``N x N`` grid (:mod:`fourier_lenslet`), results
placed on the sensor and cached per lenslet, so editing one lenslet recomputes one.
``per_lenslet_coherent`` (default where footprints overlap, e.g. Guo's touching
lenslets): lone lenslets as above; each group of overlapping lenslets has its complex
fields computed on one shared canvas, summed, and squared once (their sub-images
interfere), never cached. ``full_field``: the relayed pupil on one MLA-plane grid
covering the sensor, times the whole MLA transmission, propagated with :func:`propagate`
and integrated on pixels: the straightforward reference. Where footprints overlap "auto"
takes the cheaper of the coherent path and the full field on the sensor crop holding every
lenslet window, and always the latter when an exact propagator is asked for (the
per-lenslet transform is paraxial): :func:`resolve_method`.

Gradients: pass :class:`~lfm_studio.engine.systems.fourier_parameters.FourierParameters`
(tensor focal lengths, apertures, centres, wavelength, NA, distances, a pupil phase mask)
to a per-lenslet path (coherent groups included); the cache is then bypassed. Cache keys are derived from the spec
objects' fields (:func:`lenslet_key`), never from a hand-written list.

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from contextlib import nullcontext
from dataclasses import dataclass, field

import torch

from lfm_studio.engine.design import Design
from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.dtypes import complex_dtype
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.mla import mla_transmission
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.pixel_integration import check_pixel_integration, integrate_pixels
from lfm_studio.engine.optics.propagation import propagate
from lfm_studio.engine.optics.pupil_field import pupil_field
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.systems.fourier_lenslet import lenslet_psf, prepare_lenslet
from lfm_studio.engine.systems.fourier_parameters import (
    FourierParameters,
    LensletOptics,
    parameters_require_grad,
)
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem
from lfm_studio.engine.systems.fourier_windows import (
    LensletWindow,
    fast_samples,
    plan_window,
    shared_window,
    windows_overlap,
)
from lfm_studio.engine.systems.lenslet_cache import LensletCache, spec_parts, stable_key
from lfm_studio.engine.threads import run_in_workers, worker_count

_METHODS = ("auto", "per_lenslet", "per_lenslet_coherent", "full_field")
EXACT_PROPAGATORS = ("asm", "bandlimited_asm")
"""Propagators that make "auto" keep the full field where footprints overlap (:func:`resolve_method`)."""


@dataclass(frozen=True)
class FourierAccuracy:
    """Accuracy knobs of the Fourier-LFM PSF (each is benchmarked, run time against error).

    Attributes
    ----------
    oversampling : sub-samples per sensor pixel per axis.
    pixel_integration : ``"midpoint"`` (sum of the sub-samples, error ~ 1/s^2) or ``"fourier"``
        (exact box integral of the band-limited intensity, :func:`integrate_pixels`).
    margin_airy : diffraction margin of each lenslet window in ``lambda d / D`` (per-lenslet path).
    model : objective model, ``"debye"`` (exact defocus phase) or ``"paraxial"``.
    antialias : area-weighted lenslet aperture edges.
    dtype : ``torch.float32`` or ``torch.float64`` (fields in the matching complex dtype).
    method : ``"auto"``, ``"per_lenslet"``, ``"per_lenslet_coherent"`` or ``"full_field"``
        (:func:`resolve_method`; "auto" is per lenslet, coherent where footprints overlap).
    depth_chunk : depths per batch of the per-lenslet path (bounds memory; on CPU small chunks
        are also faster); the full-field path computes one depth at a time.
    propagator : propagation method of the full-field path (see :func:`propagate`; not
        ``"fresnel_ir"``, which changes the grid: the per-lenslet path is that method already).
    padding : zero-padding factor (>= 1) of the full-field propagation (see :func:`propagate`);
        the per-lenslet windows are sized by ``margin_airy`` instead.
    """

    oversampling: int = 3
    margin_airy: float = 32.0
    model: str = "debye"
    antialias: bool = True
    dtype: torch.dtype = torch.float32
    method: str = "auto"
    depth_chunk: int = 8
    propagator: str = "auto"
    padding: float = 2.0
    pixel_integration: str = "midpoint"

    def __post_init__(self) -> None:
        if int(self.oversampling) != self.oversampling or self.oversampling < 1:
            raise ValueError(
                f"oversampling must be an integer >= 1; got {self.oversampling!r}. Fix: use 2 or 3."
            )
        if self.method not in _METHODS:
            raise ValueError(f"method must be one of {_METHODS}; got {self.method!r}.")
        if self.margin_airy <= 0:
            raise ValueError(
                f"margin_airy must be > 0 (in lambda d / D); got {self.margin_airy!r}. Fix: use 32."
            )
        if self.depth_chunk < 1:
            raise ValueError(f"depth_chunk must be >= 1; got {self.depth_chunk!r}.")
        if not self.padding >= 1.0:
            raise ValueError(f"padding must be >= 1 (1 = none); got {self.padding!r}. Fix: use 2.")
        check_pixel_integration(self.pixel_integration)


@dataclass
class FourierPSFReport:
    """What a PSF computation did (for tests, the GUI and benchmarks)."""

    method: str = ""
    lenslets_computed: list[int] = field(default_factory=list)
    lenslets_cached: list[int] = field(default_factory=list)
    lenslets_off_sensor: list[int] = field(default_factory=list)
    """Lenslets whose window (for a coherent group: the group's canvas) lies wholly off the
    sensor: nothing computed, nothing cached (their light never reaches a pixel)."""
    coherent_groups: list[list[int]] = field(default_factory=list)
    """Lenslets whose complex fields were summed on a shared canvas (overlapping footprints)."""


# Accuracy fields that do not change a per-lenslet patch (tested by computing both): the
# path choice, the depth batching and the full-field propagation knobs.
KEY_EXEMPT_ACCURACY = ("method", "depth_chunk", "propagator", "padding")


def lenslet_key(
    system: FourierLFMSystem, lens: Lenslet, depths: tuple[float, ...], acc: FourierAccuracy, device
) -> str:
    """Cache key of one lenslet's patch, derived from the spec objects' fields (:func:`spec_key`).

    Every field of ``system`` (recursively, the objective included) except ``mla`` (the
    patch depends on its own lenslet only, keyed in full), every field of ``acc`` except
    :data:`KEY_EXEMPT_ACCURACY`, the depths and the device.
    """
    return stable_key(
        spec_parts(system, exclude=("mla",)),
        spec_parts(lens),
        spec_parts(depths),
        spec_parts(acc, exclude=KEY_EXEMPT_ACCURACY),
        str(torch.device(device)),
    )


def _origin_on_sensor(first: tuple[int, int], sensor: tuple[int, int]) -> tuple[int, int]:
    """Pixel where the on-sensor part of a patch placed at ``first`` starts (clamped to the sensor)."""
    return min(max(first[0], 0), sensor[0]), min(max(first[1], 0), sensor[1])


def _on_sensor(patch: torch.Tensor, first: tuple[int, int], sensor: tuple[int, int]) -> torch.Tensor:
    """The part of ``patch (Z, h, w)`` placed at pixel ``first`` that lies on a ``sensor`` (rows,
    cols), as its own compact tensor (a view would keep the whole patch alive); it starts at
    :func:`_origin_on_sensor`."""
    _, h, w = patch.shape
    (r0, c0), (rs, cs) = first, _origin_on_sensor(first, sensor)
    re, ce = max(min(r0 + h, sensor[0]), rs), max(min(c0 + w, sensor[1]), cs)
    if (re - rs, ce - cs) == (h, w):
        return patch
    return patch[:, rs - r0 : re - r0, cs - c0 : ce - c0].clone(memory_format=torch.contiguous_format)


def _window_on_sensor(first: tuple[int, int], pixels: int, sensor: tuple[int, int]) -> bool:
    """Whether a square window of ``pixels`` per side placed at pixel ``first`` overlaps a
    ``sensor`` (rows, cols) at all: exactly when :func:`_place` would add something."""
    return all(f < n and f + pixels > 0 for f, n in zip(first, sensor, strict=True))


def _place(target: torch.Tensor, patch: torch.Tensor, first: tuple[int, int]) -> None:
    """Add ``patch (Z, h, w)`` into ``target (Z, H, W)`` at pixel ``first`` (clipped to the sensor)."""
    _, h, w = patch.shape
    _, big_h, big_w = target.shape
    r0, c0 = first
    rs, cs = max(r0, 0), max(c0, 0)
    re, ce = min(r0 + h, big_h), min(c0 + w, big_w)
    if rs >= re or cs >= ce:
        return
    target[:, rs:re, cs:ce] += patch[:, rs - r0 : re - r0, cs - c0 : ce - c0]


def overlap_groups(system: FourierLFMSystem, windows: list[LensletWindow]) -> list[list[int]]:
    """Lenslet indices grouped into connected sets of overlapping light footprints (singletons
    for lenslets that overlap none), in index order."""
    lenslets = system.mla.lenslets
    parent = list(range(len(windows)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(len(windows)):
        for j in range(i + 1, len(windows)):
            if windows_overlap(windows[i], windows[j], lenslets[i].center, lenslets[j].center):
                parent[root(j)] = root(i)
    groups: dict[int, list[int]] = {}
    for i in range(len(windows)):
        groups.setdefault(root(i), []).append(i)
    return sorted(groups.values())


def resolve_method(
    system: FourierLFMSystem, depths: tuple[float, ...], accuracy: FourierAccuracy
) -> tuple[str, list[LensletWindow]]:
    """The path :func:`fourier_psf_stack` takes and the lenslet windows planned for it.

    "auto" gives ``"per_lenslet"`` when no two lenslet footprints overlap on the sensor, else
    ``"per_lenslet_coherent"``: overlapping lenslets' complex fields are added on a shared
    canvas before the modulus is taken (their sub-images interfere). The per-lenslet transform
    is paraxial (Fresnel), and where footprints overlap the cross terms at wide angles carry
    that error (Guo's FLFM: 0.6-0.7 % at +-40 um, as the full field with ``fresnel_tf``), so
    when an exact propagator is asked for (``propagator`` ``"asm"`` or ``"bandlimited_asm"``,
    as in the reference preset) "auto" keeps the full field there. Otherwise "auto" takes the
    cheaper of the coherent path and the full field on the sensor crop the windows cover
    (:func:`_coherent_cost`, :func:`_full_field_cost`; the full field is exact in propagation,
    so it wins ties): for Guo's 3 x 3 touching lenslets that is the cropped full field (both
    about 35x faster than the whole 2048^2 field; docs/benchmarks.md), for a few overlapping
    lenslets in a wide array the coherent groups. With ``parameters`` (gradients)
    :func:`fourier_psf_stack` takes the coherent path instead of an "auto" full field.
    ``"per_lenslet"`` asked for explicitly adds intensities even where footprints overlap
    (interference lost).
    """
    windows = [
        plan_window(
            system, lens, depths, oversampling=accuracy.oversampling, margin_airy=accuracy.margin_airy
        )
        for lens in system.mla.lenslets
    ]
    method = accuracy.method
    if method == "auto":
        groups = overlap_groups(system, windows)
        if not any(len(g) > 1 for g in groups):
            method = "per_lenslet"
        elif accuracy.propagator in EXACT_PROPAGATORS:
            method = "full_field"
        else:
            coherent = _coherent_cost(system, windows, groups, accuracy.oversampling)
            full = _full_field_cost(system, _footprint_crop(system, windows, accuracy.oversampling), accuracy)
            method = "full_field" if full <= coherent else "per_lenslet_coherent"
    return method, windows


def _coherent_cost(
    system: FourierLFMSystem, windows: list[LensletWindow], groups: list[list[int]], oversampling: int
) -> float:
    """FFT samples of the per-lenslet paths: each lone lenslet's window, and per group, each
    member on the group's canvas (:func:`_group_canvas`)."""
    cost = 0.0
    for group in groups:
        if len(group) == 1:
            cost += windows[group[0]].samples ** 2
        else:
            cost += len(group) * _group_canvas(windows, group, oversampling)[1] ** 2
    return cost


def _full_field_cost(system: FourierLFMSystem, crop: tuple[int, int] | None, acc: FourierAccuracy) -> float:
    """Samples of the full field's padded propagation grid on ``crop`` (:func:`_full_field`).

    Comparable with :func:`_coherent_cost` as it is: on Guo's FLFM (2048^2, s = 1-3) one sample
    of either cost about the same time (coherent 9 x 810^2 samples: 0.33 s per depth; full
    field on the 488^2 crop, 1952^2 padded samples: 0.25 s; 1 thread)."""
    ny, nx = crop or system.sensor_shape
    grid = _full_field_grid(system, (ny, nx))
    return (grid[0] * acc.oversampling * acc.padding) * (grid[1] * acc.oversampling * acc.padding)


def footprints_overlap(
    system: FourierLFMSystem, depths: tuple[float, ...], accuracy: FourierAccuracy
) -> bool:
    """Whether any two lenslets' light footprints overlap on the sensor (sub-images interfere)."""
    _, windows = resolve_method(system, depths, dataclasses.replace(accuracy, method="full_field"))
    return any(len(g) > 1 for g in overlap_groups(system, windows))


def fourier_psf_stack(
    system: FourierLFMSystem,
    depths: tuple[float, ...],
    *,
    accuracy: FourierAccuracy | None = None,
    device: torch.device | str = "cpu",
    cache: LensletCache | None = None,
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
    report: FourierPSFReport | None = None,
    design: Design | None = None,
    source_position: tuple[float, float] = (0.0, 0.0),
    parameters: FourierParameters | None = None,
) -> PSFStack:
    """PSF stack of a Fourier LFM: power per sensor pixel of a unit-power on-axis emitter per depth.

    Parameters
    ----------
    system : the microscope (SI units).
    depths : source depths in metres (sample side, positive away from the objective).
    accuracy : knobs (:class:`FourierAccuracy`); default = standard.
    device : where to compute.
    cache : per-lenslet cache (per-lenslet path); ``None`` computes everything.
    progress, cancel : see :mod:`lfm_studio.engine.progress`.
    report : filled with what was computed (method, lenslets computed / from cache).
    design : provenance stored in the stack.
    source_position : lateral emitter position (x0, y0) in metres; the stack of a
        shift-invariant system uses the on-axis source (the default). Off-axis sources
        are for checks (every sub-image moves by ``magnification * x0``) and are not cached.
    parameters : tensor overrides of the optics (:class:`FourierParameters`) for gradients:
        the geometry is planned from their values, the physics evaluated from the tensors
        (per-lenslet paths only). The cache is bypassed whenever parameters are given or any
        input (a lenslet focal length, an objective field) requires grad.

    Returns
    -------
    PSFStack with data ``(Z, ny, nx)`` on ``device``.
    """
    acc = accuracy or FourierAccuracy()
    depths = tuple(float(z) for z in depths)
    if not depths:
        raise ValueError("depths is empty. Fix: give at least one depth in metres.")
    report = report if report is not None else FourierPSFReport()
    if parameters is not None:
        system = parameters.applied_to(system)  # geometry from the values
    method, windows = resolve_method(system, depths, acc)
    gradients = parameters is not None or parameters_require_grad(None, system)
    if method == "full_field" and acc.method == "auto" and gradients:
        method = "per_lenslet_coherent"  # differentiable (paraxial; see resolve_method)
    report.method = method
    z = torch.tensor(depths, dtype=torch.float64, device=device)
    if parameters is not None and method == "full_field":
        raise ValueError(
            "parameters need the per-lenslet path (coherent where lenslet footprints overlap); this "
            "design was asked for method 'full_field'. Fix: use FourierAccuracy(method='auto'), or drop "
            "parameters."
        )
    crop = None
    if method == "full_field":
        # "auto" chose the full field for overlapping footprints: only the sensor region the
        # lenslet windows cover is computed (the same field there; the light beyond the windows
        # is left out, as on the per-lenslet paths). Asked for explicitly, or for an off-axis
        # source (the windows are planned on axis): the whole sensor.
        on_axis = source_position == (0.0, 0.0)
        crop = (
            _footprint_crop(system, windows, acc.oversampling) if acc.method == "auto" and on_axis else None
        )
        data = _full_field_on(system, crop, z, acc, device, progress, cancel, source_position)
    else:
        if source_position != (0.0, 0.0) or parameters is not None or parameters_require_grad(None, system):
            cache = None
        groups = (
            overlap_groups(system, windows)
            if method == "per_lenslet_coherent"
            else [[i] for i in range(len(windows))]
        )
        report.coherent_groups = [g for g in groups if len(g) > 1]
        data = _per_lenslet(
            system, windows, groups, depths, z, acc, device, cache, progress, cancel, report,
            source_position, parameters,
        )  # fmt: skip
    return PSFStack(
        data,
        depths,
        system.pixel_pitch,
        system.magnification,
        system.wavelength,
        design=design,
        metadata={
            "method": method,
            "coherent_lenslets": sum(len(g) for g in report.coherent_groups),
            "full_field_pixels": list(crop or system.sensor_shape) if method == "full_field" else None,
            "oversampling": acc.oversampling,
            "model": acc.model,
            "pixel_integration": acc.pixel_integration,
        },
    )


def _optics(system, parameters, index):
    lens = system.mla.lenslets[index]
    return parameters.lenslet(system, index) if parameters is not None else LensletOptics.of(system, lens)


def _per_lenslet(
    system, windows, groups, depths, z, acc, device, cache, progress, cancel, report, source, parameters
) -> torch.Tensor:
    """Lone lenslets: power patches (cached); each group of overlapping lenslets: complex
    fields summed on one canvas (:func:`_coherent_group`, never cached). A lenslet whose window
    (a group whose canvas) misses the sensor is skipped: its on-sensor part is empty, so the
    result is the same (gradients too: none reaches it), and it is listed in
    ``report.lenslets_off_sensor``; when every lenslet misses, a :class:`DesignWarning` says the
    PSF is zero."""
    out = torch.zeros((len(depths), *system.sensor_shape), dtype=acc.dtype, device=device)
    total = len(windows)
    todo: list[tuple[int, str]] = []  # lone lenslets to compute: (index, cache key)
    with cache.stack_round() if cache is not None else nullcontext():  # closed even when a lenslet raises
        done = skipped = 0
        s, sensor = acc.oversampling, system.sensor_shape
        for group in groups:
            if len(group) > 1:
                corner, samples = _group_canvas(windows, group, s)
                if not _window_on_sensor(corner, samples // s, sensor):
                    report.lenslets_off_sensor.extend(group)
                    done += len(group)
                    skipped += len(group)
                    continue
                _coherent_group(system, windows, group, z, acc, device, source, parameters, out, cancel)
                report.lenslets_computed.extend(group)
                done += len(group)
                checkpoint(cancel, progress, done, total, f"lenslets {done}/{total} (coherent group)")
                continue
            (index,) = group
            lens, window = system.mla.lenslets[index], windows[index]
            if not _window_on_sensor(window.first_pixel, window.pixels(s), sensor):
                report.lenslets_off_sensor.append(index)
                done += 1
                skipped += 1
                continue
            key = lenslet_key(system, lens, depths, acc, device) if cache is not None else ""
            patch = cache.get(key) if cache is not None else None
            if patch is None:
                todo.append((index, key))
                continue
            report.lenslets_cached.append(index)
            _place(out, patch, _origin_on_sensor(window.first_pixel, sensor))
            done += 1
            checkpoint(cancel, progress, done, total, f"lenslet {done}/{total} (cached)")

        def compute(item: tuple[int, str]) -> torch.Tensor:
            index, _ = item
            lens, window = system.mla.lenslets[index], windows[index]
            patch = lenslet_psf(
                system, lens, window, z, oversampling=acc.oversampling, model=acc.model,
                antialias=acc.antialias, dtype=acc.dtype, source_position=source, depth_chunk=acc.depth_chunk,
                pixel_integration=acc.pixel_integration, optics=_optics(system, parameters, index),
            )  # fmt: skip
            # Only the sensor's part is ever used (the key holds the sensor shape): store just that.
            return _on_sensor(patch, window.first_pixel, sensor)

        def place(position: int, patch: torch.Tensor) -> None:  # on the caller's thread
            nonlocal done
            index, key = todo[position]
            if cache is not None:
                cache.put(key, patch)
            _place(out, patch, _origin_on_sensor(windows[index].first_pixel, sensor))
            done += 1
            checkpoint(cancel, progress, done, total, f"lenslet {done}/{total}")

        # Lone lenslets on worker threads, each patch placed on this thread in lenslet order:
        # patches add into shared pixels (float sums) and the cache keeps the first ones.
        recording = torch.is_grad_enabled() and (
            parameters is not None or parameters_require_grad(None, system)
        )
        workers = worker_count(None, out.device, recording)
        checkpoint(cancel, progress, done, total, f"lenslets {done}/{total}")
        run_in_workers(compute, todo, workers, on_result=place, collect=False, in_order=True)
        report.lenslets_computed.extend(index for index, _ in todo)  # lenslet order, not finishing order
    if total and skipped == total:
        warnings.warn(
            f"no lenslet's light reaches the {sensor[0]} x {sensor[1]} px sensor (crop); the PSF is "
            "zero. Fix: a larger sensor crop, or lenslets closer to the axis.",
            DesignWarning,
            stacklevel=3,
        )
    checkpoint(cancel, progress, total, total, "done")
    return out


def _group_canvas(
    windows: list[LensletWindow], group: list[int], oversampling: int
) -> tuple[tuple[int, int], int]:
    """Top-left sensor pixel and samples per side of a group's shared square canvas: the
    bounding box of the members' windows, centred in a square of a fast FFT length."""
    s = oversampling
    first = [windows[i].first_pixel for i in group]
    size = [windows[i].pixels(s) for i in group]
    r0, c0 = min(f[0] for f in first), min(f[1] for f in first)
    rows = max(f[0] + n for f, n in zip(first, size, strict=True)) - r0
    cols = max(f[1] + n for f, n in zip(first, size, strict=True)) - c0
    samples = fast_samples(max(rows, cols), s)
    pixels = samples // s
    return (r0 - (pixels - rows) // 2, c0 - (pixels - cols) // 2), samples


def _coherent_group(system, windows, group, z, acc, device, source, parameters, out, cancel) -> None:
    """Add the power of a group of overlapping lenslets into ``out``.

    Every lenslet of the group is computed on one shared square canvas (:func:`shared_window`)
    covering the bounding box of the group's own windows, so each field is known wherever
    the others carry light (a field cut at its own window would drop the cross terms
    ``2 Re(E_a* E_b)`` there, which fall off with the field, not the intensity). Per depth
    chunk the complex fields (:func:`~lfm_studio.engine.systems.fourier_lenslet.lenslet_field`) are summed and ``|sum E_k|^2`` is
    integrated on pixels once. Off-sensor parts of the canvas are cropped at placing.
    """
    s = acc.oversampling
    lenslets = system.mla.lenslets
    corner, samples = _group_canvas(windows, group, s)
    shared = {
        i: shared_window(system, lenslets[i], windows[i], corner, samples, oversampling=s) for i in group
    }
    inputs = [
        prepare_lenslet(
            system, lenslets[i], shared[i], z, s, acc.model, acc.antialias, acc.dtype, source, optics
        )
        for i, optics in ((i, _optics(system, parameters, i)) for i in group)
    ]
    for start in range(0, z.numel(), acc.depth_chunk):
        checkpoint(cancel, None, 0, 1, "")
        zc = z[start : start + acc.depth_chunk]
        total = None
        for lenslet_input in inputs:
            field = lenslet_input.field(zc)
            if total is None:
                total = field
            elif total.requires_grad or field.requires_grad:
                total = total + field  # out of place: the first field may be a leaf of the graph
            else:
                total = total.add_(field)
        assert total is not None
        power = integrate_pixels(total.real**2 + total.imag**2, s, acc.pixel_integration)
        if power.requires_grad:
            # Autograd refuses an in-place add through a view of a view of ``out`` here: place a
            # full-depth patch (zeros outside this chunk) instead.
            after = out.shape[0] - start - zc.numel()
            _place(out, torch.nn.functional.pad(power, (0, 0, 0, 0, start, after)), corner)
        else:
            _place(out[start : start + zc.numel()], power, corner)


def _shifted_mla(mla: MicrolensArray, shift: tuple[float, float]) -> MicrolensArray:
    """The array moved by ``-shift`` (x, y) metres, without an aperture check (a sub-pixel move)."""
    moved = tuple(
        Lenslet(
            (lens.center[0] - shift[0], lens.center[1] - shift[1]),
            lens.aperture_diameter,
            lens.focal_length,
            lens.shape,
        )
        for lens in mla.lenslets
    )
    return MicrolensArray(moved)


def _mla_half_extent(mla: MicrolensArray) -> tuple[float, float]:
    """Half-extent (y, x) in metres of the bounding box of all lenslet apertures."""
    ys = [abs(lens.center[1]) + lens.aperture_diameter / 2.0 for lens in mla.lenslets]
    xs = [abs(lens.center[0]) + lens.aperture_diameter / 2.0 for lens in mla.lenslets]
    return max(ys), max(xs)


def _full_field_grid(system: FourierLFMSystem, shape: tuple[int, int]) -> tuple[int, int]:
    """Pixels (y, x) of the full field's MLA-plane grid for a sensor of ``shape``: whole pixels
    around it so the grid holds every lenslet too, with a 10 % margin (same parity as the
    sensor, so the sensor stays centred in it)."""
    ny, nx = shape
    half_y, half_x = (1.1 * h for h in _mla_half_extent(system.mla))  # clear of the window edge
    pad_y = max(0, math.ceil(half_y / system.pixel_pitch - ny / 2.0) + 1)
    pad_x = max(0, math.ceil(half_x / system.pixel_pitch - nx / 2.0) + 1)
    return ny + 2 * pad_y, nx + 2 * pad_x


def _footprint_crop(
    system: FourierLFMSystem, windows: list[LensletWindow], oversampling: int
) -> tuple[int, int] | None:
    """Smallest sensor crop centred on the axis (same parity as the sensor) holding every
    lenslet window; ``None`` when that is the whole sensor."""
    shape = []
    for axis, n in enumerate(system.sensor_shape):
        reach = max(
            max(n // 2 - w.first_pixel[axis], w.first_pixel[axis] + w.pixels(oversampling) - n // 2)
            for w in windows
        )
        shape.append(min(n, 2 * (reach + 1) + n % 2))
    return None if tuple(shape) == system.sensor_shape else (shape[0], shape[1])


def _full_field_on(system, crop, z, acc, device, progress, cancel, source) -> torch.Tensor:
    """:func:`_full_field` on a centred ``crop`` of the sensor (``None``: all of it), pasted
    into a zero sensor: pixel ``j`` of the crop is pixel ``j + n//2 - m//2`` of the sensor."""
    if crop is None:
        return _full_field(system, z, acc, device, progress, cancel, source)
    part = _full_field(
        dataclasses.replace(system, sensor_shape=crop), z, acc, device, progress, cancel, source
    )
    out = torch.zeros((z.numel(), *system.sensor_shape), dtype=part.dtype, device=device)
    (ny, nx), (my, mx) = system.sensor_shape, crop
    r0, c0 = ny // 2 - my // 2, nx // 2 - mx // 2
    out[:, r0 : r0 + my, c0 : c0 + mx] = part
    return out


def _full_field(system, z, acc, device, progress, cancel, source) -> torch.Tensor:
    if acc.propagator == "fresnel_ir":
        raise ValueError(
            "propagator 'fresnel_ir' cannot feed the full-field pixel integration: its output grid "
            "(spacing lambda d / (M dx)) is not the sensor's sub-pixel grid. Fix: use 'auto', "
            "'bandlimited_asm', 'asm' or 'fresnel_tf' (the per-lenslet path is the single-FFT Fresnel transform)."
        )
    s = acc.oversampling
    step = system.pixel_pitch / s
    ny, nx = system.sensor_shape
    big_y, big_x = _full_field_grid(system, (ny, nx))
    pad_y, pad_x = (big_y - ny) // 2, (big_x - nx) // 2
    grid = Grid((big_y * s, big_x * s), step)
    # Evaluate at sub-pixel centres: grid sample q sits at (q - Q//2) step; pixel j's
    # sub-sample m must sit at (j - P//2) p - p/2 + (m + 1/2) step (q = j s + m).
    eps_y = (grid.ny // 2 - s * (big_y // 2) - (s - 1) / 2.0) * step
    eps_x = (grid.nx // 2 - s * (big_x // 2) - (s - 1) / 2.0) * step
    m_r = system.relay_magnification
    cdtype = complex_dtype(acc.dtype)
    mla = mla_transmission(
        _shifted_mla(system.mla, (eps_x, eps_y)), grid, system.wavelength,
        antialias=acc.antialias, dtype=cdtype, device=device,
    )  # fmt: skip
    out = torch.zeros((z.numel(), ny, nx), dtype=acc.dtype, device=device)
    for i in range(z.numel()):
        checkpoint(cancel, progress, i, z.numel(), f"depth {i + 1}/{z.numel()} (full field)")
        relayed = pupil_field(
            system.objective, Grid(grid.shape, step / m_r), system.wavelength, z[i : i + 1],
            position=(-source[0], -source[1]), model=acc.model, center=(eps_x / m_r, eps_y / m_r),
            check_sampling=False, zernike_waves=dict(system.pupil_zernike_waves), dtype=cdtype, device=device,
        )  # fmt: skip
        field = relayed.with_data(relayed.data / m_r * mla, grid=grid)
        at_sensor = propagate(field, system.mla_to_camera, method=acc.propagator, padding=acc.padding)
        power = integrate_pixels(at_sensor.intensity() * (step * step), s, acc.pixel_integration)[0]
        out[i] = power[pad_y : pad_y + ny, pad_x : pad_x + nx].to(acc.dtype)
    checkpoint(cancel, progress, z.numel(), z.numel(), "done")
    return out
