"""Light-field patterns of a conventional LFM: one sensor pattern per depth and voxel sub-position.

For a point at depth ``z`` on the lenslet axis, the native-image-plane (NIP) field is
the image-side Debye field (:func:`debye_psf`), computed once for all depths on a grid
of ``Ns`` samples per lenslet pitch (``Ns`` a multiple of ``voxels_per_lenslet``), so a
voxel ``a`` sub-positions off axis is the same field shifted by ``a Ns / S`` samples.

Each lenslet within the light's reach cuts its ``Ns x Ns`` patch and carries it to the
sensor with the Fresnel integral (thesis eq. 3.11), evaluated as a separable matrix
product straight onto the sensor's sub-pixel centres over a window of three pitches
(its own and one neighbour each side). Lenslet centres are whole pixels apart, so every
lenslet shares one matrix and all windows land on one sensor grid, where they add as
*complex fields*: a lenslet's light interferes with its neighbours' diffraction tails,
and adding intensities instead is off by 5-10 % at defocus (measured against a
full-field simulation; tests). ``|U|^2`` is then integrated on the rectified pixels.

A lenslet's clear aperture (``system.lenslet_aperture``, default the pitch) is applied to its
patch as an antialiased coverage; the grid is planned from the pitch whatever the aperture.

Gradients: ``lenslet_focal_length``, ``mla_to_camera``, ``wavelength`` and ``lenslet_aperture``
may be given as 0-d tensors that override the system's floats in the physics (the lens and
Fresnel phases, the Debye integrand, the aperture coverage) while every discrete choice
(sample counts, grids, reach, lit lenslets) stays planned from the system's floats; a tensor
NA travels in ``system.objective``. At the system's values the result equals the float path's.
``zernike_waves`` (``{noll index: waves}``, floats or 0-d tensors, ``m = 0`` terms) overrides or adds
terms of the system's pupil phase (``system.pupil_zernike_waves``) in the Debye integrand.

The square lattice is symmetric under x and y mirrors and the transpose, so of the
``S x S`` sub-positions only those with ``0 <= a <= b`` are simulated and the rest are
mirrored copies (6 of 25 for ``S = 5``).

The thesis: J. Sun, "Computational Framework for Light-Field Microscopy Simulation and Optimization" (docs/references.md).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import torch

from lfm_studio.engine.optics.debye import debye_psf
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.objective import _value
from lfm_studio.engine.optics.phase_kernels import (
    aperture_coverage,
    fresnel_chirp,
    lens_phase,
    shift_ramp,
    wavenumber,
)
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem

DEBYE_DEPTHS = 4  # depths per Debye evaluation of the NIP fields (bounds its temporaries)
Scalar = float | torch.Tensor
OUTPUT_OVERSAMPLING = 1.4  # sensor-field samples per Nyquist interval of the sub-image intensity


def light_radius(system: ConventionalLFMSystem, depths: tuple[float, ...], margin: float = 12.0) -> float:
    """NIP radius (m) around a source's image that holds its light at ``depths``:
    the geometric blur plus ``margin`` diffraction lengths ``lambda / NA_img``.

    The Debye field's Airy tails fall off slowly: lenslets beyond this radius change a
    pattern by 0.25 % (margin 8), 0.1 % (12, default) or < 0.02 % (20), measured on the
    10x/0.3 test system.
    """
    na_image = _value(system.objective.numerical_aperture) / system.magnification
    return max(system.blur_radius(z) for z in depths) + margin * system.wavelength / na_image


def samples_per_pitch(system: ConventionalLFMSystem, oversampling: float = 1.0) -> int:
    """NIP samples per pitch ``Ns``: a multiple of ``S`` (odd), at Nyquist for the image-side NA,
    and alias-free for the three-pitch lenslet window, times ``oversampling`` (>= 1).

    The sampled Fresnel sum repeats its output every ``lambda d / dx``; the window
    ``3 P`` must be shorter: ``Ns > 3 P^2 / (lambda d)``.
    """
    if not oversampling >= 1.0:
        raise ValueError(
            f"NIP oversampling must be >= 1; got {oversampling!r}. Fix: use 1 (the minimum grid)."
        )
    s = system.voxels_per_lenslet
    na_image = _value(system.objective.numerical_aperture) / system.magnification
    nyquist = math.ceil(2.0 * system.pitch * na_image / system.wavelength) + 1
    alias_free = math.floor(3.0 * system.pitch**2 / (system.wavelength * system.mla_to_camera)) + 1
    per_voxel = math.ceil(max(alias_free, nyquist) * oversampling / s)
    per_voxel += 1 - per_voxel % 2  # odd, so each patch is centred on its lenslet
    return s * per_voxel


def nip_field_size(system: ConventionalLFMSystem, reach: int, oversampling: float = 1.0) -> int:
    """NIP samples per side needed for ``reach`` lenslets plus the sub-position shifts (odd)."""
    ns = samples_per_pitch(system, oversampling)
    return (2 * reach + 1) * ns + 2 * (system.voxels_per_lenslet // 2) * (ns // system.voxels_per_lenslet)


def nip_fields(
    system: ConventionalLFMSystem,
    depths: tuple[float, ...],
    *,
    reach: int,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str = "cpu",
    radial_sampling: int | str = 8,
    model: str = "debye",
    n_quadrature: int | None = None,
    oversampling: float = 1.0,
    wavelength: Scalar | None = None,
    zernike_waves: Mapping[int, Scalar] | None = None,
) -> torch.Tensor:
    """Image-side Debye fields ``(Z, N, N)`` of an on-axis point at each depth on the NIP grid.

    ``mirrored(nip_quadrants(...))`` with the same arguments (see there).
    """
    quadrants = nip_quadrants(
        system, depths, reach=reach, dtype=dtype, device=device, radial_sampling=radial_sampling,
        model=model, n_quadrature=n_quadrature, oversampling=oversampling, wavelength=wavelength,
        zernike_waves=zernike_waves,
    )  # fmt: skip
    return mirrored(quadrants, nip_field_size(system, reach, oversampling))


def nip_quadrants(
    system: ConventionalLFMSystem,
    depths: tuple[float, ...],
    *,
    reach: int,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str = "cpu",
    radial_sampling: int | str = 8,
    model: str = "debye",
    n_quadrature: int | None = None,
    oversampling: float = 1.0,
    wavelength: Scalar | None = None,
    zernike_waves: Mapping[int, Scalar] | None = None,
) -> torch.Tensor:
    """One quadrant ``(Z, h + 1, h + 1)`` of the on-axis NIP fields, ``h = N // 2`` (:func:`mirrored`
    expands it): a quarter of the memory of the fields, kept for all depths during a build.

    :data:`DEBYE_DEPTHS` depths per Debye call (the Bessel table in ``(radius, theta)`` is
    shared by the depths of a call). ``radial_sampling`` is the radial-table oversampling of :func:`debye_psf`
    (8: interpolation error <= (k NA h)^4 / 384 ~ 2e-6 of the peak at Nyquist-sampled grids);
    ``model`` and ``n_quadrature`` are those of :func:`debye_psf`; ``oversampling`` is the NIP
    grid factor of :func:`samples_per_pitch`. ``wavelength`` (a float or 0-d tensor, metres)
    overrides the system's in the Debye integrand (gradients flow to it); the grid stays
    planned from ``system.wavelength``. The pupil phase is ``system.pupil_zernike_waves`` with
    ``zernike_waves`` (floats or 0-d tensors, waves) overriding or adding terms (:func:`pupil_waves`).
    """
    n = nip_field_size(system, reach, oversampling)
    dx = system.pitch / samples_per_pitch(system, oversampling)
    z = torch.tensor(depths, dtype=torch.float64, device=device)
    cdtype = torch.complex64 if dtype == torch.float32 else torch.complex128
    # The on-axis field is radially symmetric and the grid (odd n) centred on it: compute
    # one quadrant, samples 0..h from the axis (a source offset puts the image centre on
    # the quadrant's first sample); mirrored() expands it.
    h = n // 2
    quadrant = Grid(h + 1, dx)
    offset = ((h + 1) // 2) * dx / system.magnification  # object side; the image is inverted
    lam = system.wavelength if wavelength is None else wavelength
    waves = pupil_waves(system, zernike_waves)
    out = torch.empty((len(depths), h + 1, h + 1), dtype=cdtype, device=device)
    # A few depths per Debye call: its interpolation temporaries are complex128 per depth and
    # sample (about 15x the complex64 result), so one call for 31 depths on a 518^2 quadrant
    # peaked at 490 MB above the result; the radial tables are per depth anyway.
    for start in range(0, len(depths), DEBYE_DEPTHS):
        part = slice(start, min(len(depths), start + DEBYE_DEPTHS))
        field = debye_psf(
            system.objective, quadrant, lam, z[part], position=(offset, offset),
            image_side=True, radial_sampling=radial_sampling, model=model, n_quadrature=n_quadrature,
            dtype=cdtype, device=device, zernike_waves=waves,
        )  # fmt: skip
        out[part] = field.data.reshape(-1, h + 1, h + 1)
    return out


def pupil_waves(
    system: ConventionalLFMSystem, zernike_waves: Mapping[int, Scalar] | None = None
) -> dict[int, Scalar] | None:
    """The pupil phase ``{noll index: waves}`` of ``system`` with ``zernike_waves`` overriding or
    adding terms; ``None`` when there is none (the unmasked Debye computation, unchanged)."""
    waves: dict[int, Scalar] = dict(system.pupil_zernike_waves)
    waves.update(zernike_waves or {})
    return waves or None


def mirrored(quadrants: torch.Tensor, n: int) -> torch.Tensor:
    """The centred ``(Z, n, n)`` fields (``n`` odd, ``n // 2`` below the quadrant's size) from
    quadrants ``(Z, h + 1, h + 1)`` holding samples ``0..h`` from the axis."""
    if n % 2 == 0 or n // 2 >= quadrants.shape[-1]:
        raise ValueError(f"n must be odd and at most {2 * quadrants.shape[-1] - 1}; got {n}.")
    mirror = (torch.arange(n, device=quadrants.device) - n // 2).abs()
    return quadrants.index_select(-2, mirror).index_select(-1, mirror)


def _unique_offsets(half: int) -> list[tuple[int, int]]:
    return [(a, b) for a in range(half + 1) for b in range(a, half + 1)]


def sub_samples(system: ConventionalLFMSystem, oversampling: float = OUTPUT_OVERSAMPLING) -> int:
    """Sensor-field samples per pixel per axis (odd, one on each pixel centre).

    A lenslet's sub-image intensity is band-limited to ``2 P / (lambda d)``; its field is
    sampled ``oversampling`` times finer than that Nyquist interval ``lambda d / (2 P)``
    before the midpoint-rule pixel integration (convergence study in the tests).
    """
    nyquist = system.wavelength * system.mla_to_camera / (2.0 * system.pitch)
    count = math.ceil(system.pixel_size * oversampling / nyquist)
    return count + 1 - count % 2


def lenslet_transform(
    system: ConventionalLFMSystem,
    ns: int,
    out_n: int,
    *,
    device: torch.device | str = "cpu",
    lenslet_focal_length: Scalar | None = None,
    mla_to_camera: Scalar | None = None,
    wavelength: Scalar | None = None,
) -> torch.Tensor:
    """Separable Fresnel transform of one lenslet, as an ``(out_n, ns)`` complex128 matrix ``T``.

    The sensor field behind a lenslet, at output samples ``u = (i - out_n//2) P / (Q m)``
    about its centre, from NIP samples ``x = (k - ns//2) P / ns`` of its patch, is
    ``T @ patch @ T.T`` with (thesis eq. 3.11, per axis; the phases of
    :mod:`~lfm_studio.engine.optics.phase_kernels`)

        T[i, k] = dx / sqrt(lambda d) exp(j k [u^2 / (2d) - u x / d + x^2 (1/d - 1/f) / 2]).

    The output chirp is kept: adjacent lenslets' fields add coherently on the sensor.
    The constant ``exp(j k d) / j`` is common to all lenslets and dropped.
    ``lenslet_focal_length``, ``mla_to_camera`` and ``wavelength`` (floats or 0-d tensors,
    metres) override the system's values in the physics (gradients flow to them); the
    sampling stays planned from the system.
    """
    dx = system.pitch / ns
    out_step = system.pitch * 3 / out_n  # out_n spans three pitches
    x = (torch.arange(ns, device=device, dtype=torch.float64) - ns // 2) * dx
    u = (torch.arange(out_n, device=device, dtype=torch.float64) - out_n // 2) * out_step
    lam = system.wavelength if wavelength is None else wavelength
    k = wavenumber(lam)
    d = system.mla_to_camera if mla_to_camera is None else mla_to_camera
    f = system.lenslet_focal_length if lenslet_focal_length is None else lenslet_focal_length
    xs, us = x[None, :], u[:, None]
    phase = (
        fresnel_chirp(us, 0.0, d, k)
        + shift_ramp(xs, 0.0, (us, 0.0), k, d)
        + fresnel_chirp(xs, 0.0, d, k)
        + lens_phase(xs, 0.0, f, k)
    )
    amplitude = dx / (lam * d) ** 0.5
    if not isinstance(amplitude, torch.Tensor):
        amplitude = torch.tensor(amplitude, dtype=torch.float64, device=device)
    return torch.polar(amplitude.to(torch.float64).expand_as(phase), phase)


def conventional_patterns(
    system: ConventionalLFMSystem,
    depths: tuple[float, ...],
    *,
    reach: int,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str = "cpu",
    progress: ProgressCallback | None = None,
    cancel: CancelToken = None,
    nip_field: torch.Tensor | None = None,
    nip_oversampling: float = 1.0,
    pixel_oversampling: float = OUTPUT_OVERSAMPLING,
    light_margin: float = 12.0,
    lenslet_focal_length: Scalar | None = None,
    mla_to_camera: Scalar | None = None,
    wavelength: Scalar | None = None,
    lenslet_aperture: Scalar | None = None,
    zernike_waves: Mapping[int, Scalar] | None = None,
) -> torch.Tensor:
    """Sensor patterns for ``depths`` sharing one lenslet reach.

    Parameters
    ----------
    system : the microscope.
    depths : depths in metres (sample side).
    reach : lenslets on each side of the source's lenslet whose light is simulated
        (``system.support(max |z|)``); the pattern covers ``reach + 1`` for the spill.
    dtype : real dtype of the patterns (fields in the matching complex dtype).
    nip_field : the on-axis NIP fields ``(Z, N, N)`` of these depths from :func:`nip_fields`
        on a grid at least as wide as this reach needs (cropped centrally); computed
        here when omitted.
    nip_oversampling, pixel_oversampling, light_margin : accuracy knobs: the NIP grid factor
        (:func:`samples_per_pitch`), the sensor-field samples per intensity Nyquist interval
        (:func:`sub_samples`) and the diffraction margin of :func:`light_radius`.
    lenslet_focal_length, mla_to_camera : optional 0-d tensors (metres) overriding the
        system's values in the lenslet transform, for gradients; the sampling is planned
        from the system's floats, so pass a system holding the same values.
    wavelength : optional 0-d tensor (metres) overriding ``system.wavelength`` in the
        physics: the Debye integrand of the NIP field (when computed here; a given
        ``nip_field`` must carry its own) and the lenslet transform. Sample counts, grids,
        the lenslet reach and the lit lenslets stay planned from ``system.wavelength``.
    lenslet_aperture : optional 0-d tensor (metres, ``<= pitch``) overriding
        ``system.lenslet_aperture`` (the clear aperture's side or diameter); it enters through
        the antialiased aperture coverage of the NIP samples (:func:`lenslet_aperture_weights`),
        the grid stays planned from the pitch. The NA reaches
        the patterns through the NIP field (a tensor NA in ``system.objective``, or a
        ``nip_field`` that carries a graph: :func:`debye_psf` is differentiable in it).
    zernike_waves : optional ``{noll index: waves}`` (floats or 0-d tensors, ``m = 0`` terms)
        overriding or adding terms of ``system.pupil_zernike_waves`` in the Debye integrand of the
        NIP field (when computed here; a given ``nip_field`` carries its own mask).

    Returns
    -------
    Tensor ``(Z, S, S, H, H)``, ``H = (2 reach + 3) Q``: power per rectified pixel of a
    unit-power emitter at each depth and voxel sub-position ``(row, col)``, in NIP
    (image) orientation, the canvas centred on the source lenslet's centre.
    """
    s = system.voxels_per_lenslet
    field_n = nip_field_size(system, reach, nip_oversampling)
    if nip_field is None:
        nip_field = nip_fields(
            system, depths, reach=reach, dtype=dtype, device=device, oversampling=nip_oversampling,
            wavelength=wavelength, zernike_waves=zernike_waves,
        )  # fmt: skip
    cut = (nip_field.shape[-1] - field_n) // 2
    if cut < 0:
        raise ValueError(f"nip_field is {nip_field.shape[-1]} samples wide; reach {reach} needs {field_n}.")
    base = nip_field[:, cut : cut + field_n, cut : cut + field_n]
    unique = {}
    # Each depth's own light radius (its blur plus the margin), not the group's widest.
    radii = [light_radius(system, (z,), light_margin) for z in depths]
    offsets = _unique_offsets(s // 2)
    rows = sorted({a for a, _ in offsets})
    for done, a in enumerate(rows):  # the sub-positions of one row share their row transform
        checkpoint(cancel, progress, done, len(rows), f"pattern row {done + 1}/{len(rows)}")
        bs = tuple(b for row, b in offsets if row == a)
        found = offset_row_patterns(
            system, base, a, bs, reach=reach, dtype=dtype, light_radius=radii,
            oversampling=pixel_oversampling, nip_oversampling=nip_oversampling,
            lenslet_focal_length=lenslet_focal_length, mla_to_camera=mla_to_camera, wavelength=wavelength,
            lenslet_aperture=lenslet_aperture,
        )  # fmt: skip
        unique.update({(a, b): pattern for b, pattern in zip(bs, found, strict=True)})
    checkpoint(cancel, progress, len(rows), len(rows), "patterns done")
    return _expand_symmetric(unique, s)


def offset_pattern(
    system: ConventionalLFMSystem,
    base: torch.Tensor,
    a: int,
    b: int,
    *,
    reach: int,
    dtype: torch.dtype,
    oversampling: float = OUTPUT_OVERSAMPLING,
    light_radius: float | None = None,
    nip_oversampling: float = 1.0,
    lenslet_focal_length: Scalar | None = None,
    mla_to_camera: Scalar | None = None,
    wavelength: Scalar | None = None,
    lenslet_aperture: Scalar | None = None,
) -> torch.Tensor:
    """Pattern ``(Z, H, H)`` of a source ``a`` sub-positions below and ``b`` right of the lenslet axis.

    ``base`` is the on-axis NIP field ``(Z, N, N)`` with ``N = nip_field_size(system, reach)``.
    Each lenslet within ``reach`` is transformed onto its window (its own pitch and one
    neighbour on each side, at ``sub_samples`` per pixel), the windows are added as
    complex fields on one sensor grid, and ``|U|^2`` is integrated on the pixels
    (:func:`sub_samples` samples per pixel, from ``oversampling``). Lenslets farther than
    ``light_radius`` (NIP metres, :func:`light_radius`) from the source's image receive no
    light and are skipped; ``None`` computes them all. ``nip_oversampling``: the NIP grid
    factor ``base`` was computed with (:func:`nip_fields`). ``lenslet_focal_length``,
    ``mla_to_camera``, ``wavelength``: tensor overrides for gradients (:func:`lenslet_transform`);
    ``lenslet_aperture``: one for the clear aperture (:func:`conventional_patterns`).
    """
    return offset_row_patterns(
        system, base, a, (b,), reach=reach, dtype=dtype, oversampling=oversampling,
        light_radius=light_radius, nip_oversampling=nip_oversampling,
        lenslet_focal_length=lenslet_focal_length, mla_to_camera=mla_to_camera, wavelength=wavelength,
        lenslet_aperture=lenslet_aperture,
    )[0]  # fmt: skip


def lit_lenslets(
    system: ConventionalLFMSystem, reach: int, a: int, b: int, radius: float | None
) -> torch.Tensor:
    """Lenslets ``(2 reach + 1)^2`` (bool) whose aperture lies within ``radius`` (NIP metres) of the
    image of a source ``(a, b)`` sub-positions off axis; all of them when ``radius`` is ``None``."""
    lit = torch.ones((2 * reach + 1, 2 * reach + 1), dtype=torch.bool)
    if radius is not None:
        p, s = system.pitch, system.voxels_per_lenslet
        ya, xb = a * p / s, b * p / s
        for i in range(-reach, reach + 1):
            for j in range(-reach, reach + 1):
                gap = math.hypot(max(abs(i * p - ya) - p / 2, 0.0), max(abs(j * p - xb) - p / 2, 0.0))
                lit[reach + i, reach + j] = gap <= radius
    return lit


def offset_row_patterns(
    system: ConventionalLFMSystem,
    base: torch.Tensor,
    a: int,
    bs: tuple[int, ...],
    *,
    reach: int,
    dtype: torch.dtype,
    oversampling: float = OUTPUT_OVERSAMPLING,
    light_radius: float | list[float] | None = None,
    nip_oversampling: float = 1.0,
    lenslet_focal_length: Scalar | None = None,
    mla_to_camera: Scalar | None = None,
    wavelength: Scalar | None = None,
    lenslet_aperture: Scalar | None = None,
) -> list[torch.Tensor]:
    """Patterns ``(Z, H, H)`` of the sources ``(a, b)`` for each ``b`` in ``bs`` (see :func:`offset_pattern`).

    Square lenslets: the sources of one row ``a`` see the same NIP rows, so the row transform
    (the first of the two GEMMs, :func:`_row_transform`) is done once on the band of
    columns all of them need, and each ``b`` crops it and zeroes its unlit lenslets after
    it (exact: the row transform keeps tiles apart). A square clear aperture smaller than the
    pitch is separable and folded into the transform's input columns
    (:func:`lenslet_aperture_weights`). Round lenslets: the aperture is not
    separable, so each ``b`` is transformed on its own. ``light_radius``: one radius for all
    depths, a list with one per depth of ``base``, or ``None`` (every lenslet lit).
    """
    m = sub_samples(system, oversampling)
    s, q = system.voxels_per_lenslet, system.pixels_per_lenslet
    ns = samples_per_pitch(system, nip_oversampling)
    step = ns // s  # NIP samples per voxel sub-position
    field_n = base.shape[-1]
    per_lenslet = q * m  # output samples per pitch (odd)
    out_n = 3 * per_lenslet  # window: the lenslet and one neighbour each side
    cdtype = torch.complex64 if dtype == torch.float32 else torch.complex128
    transform = lenslet_transform(
        system, ns, out_n, device=base.device, lenslet_focal_length=lenslet_focal_length,
        mla_to_camera=mla_to_camera, wavelength=wavelength,
    ).to(cdtype)  # fmt: skip
    aperture = system.lenslet_aperture if lenslet_aperture is None else lenslet_aperture
    tiles = 2 * reach + 1
    span = tiles * ns
    # The source's field is the on-axis field moved by (a, b) sub-positions: lenslet (i, j)
    # sees the base field around (i ns - a step, j ns - b step) from the axis. The patches of
    # lenslets -reach..reach tile one (2 reach + 1) ns square region of it.
    top = field_n // 2 - a * step - reach * ns - ns // 2
    lefts = [field_n // 2 - b * step - reach * ns - ns // 2 for b in bs]
    radii = list(light_radius) if isinstance(light_radius, (list, tuple)) else [light_radius] * base.shape[0]
    if len(radii) != base.shape[0]:
        raise ValueError(
            f"light_radius has {len(radii)} entries for {base.shape[0]} depths. Fix: one per depth."
        )
    # Bands of NIP columns to row-transform: (first column, width, pre-transform weights, the b's).
    bands: list[tuple[int, int, torch.Tensor | None, list[int]]]
    if system.lenslet_shape == "circle":
        diameter = system.pitch if aperture is None else aperture
        disk = lenslet_aperture_weights(system, ns, diameter, base.device)
        disk = disk.to(cdtype).repeat(tiles, tiles)
        bands = [(left, span, disk, [i]) for i, left in enumerate(lefts)]
    else:
        if aperture is not None:  # T @ diag(w): the separable square aperture on both axes
            transform = transform * lenslet_aperture_weights(system, ns, aperture, base.device).to(cdtype)
        bands = [(min(lefts), span + max(lefts) - min(lefts), None, list(range(len(bs))))]
    out_step = system.pitch / per_lenslet
    patterns: list[list[torch.Tensor]] = [[] for _ in bs]
    for z in range(base.shape[0]):  # one depth at a time: the GEMM temporaries stay ~50 MB
        lits = [lit_lenslets(system, reach, a, b, radii[z]).to(device=base.device) for b in bs]
        for first, width, weights, members in bands:
            region = base[z, top : top + span, first : first + width].to(cdtype)
            if weights is not None:
                region = region * weights
            rows = _row_transform(transform, region, tiles)  # (3, p, tiles, width)
            for index in members:
                crop = rows[..., lefts[index] - first : lefts[index] - first + span]
                field = _column_transform(transform, crop, lits[index])
                power = (field.real**2 + field.imag**2) * (out_step * out_step)
                patterns[index].append(_bin(power[None], m).to(dtype))
    return [torch.cat(per_b, dim=0) for per_b in patterns]


def lenslet_aperture_weights(
    system: ConventionalLFMSystem, ns: int, aperture: Scalar, device: torch.device | str = "cpu"
) -> torch.Tensor:
    """Antialiased clear-aperture coverage of a lenslet's ``ns`` NIP samples per pitch (float64):
    ``(ns, ns)`` for a circle of diameter ``aperture``, the per-axis ``(ns,)`` factor for a
    square of side ``aperture`` (the 2-D coverage is its outer product). Differentiable in
    a tensor ``aperture``."""
    dx = system.pitch / ns
    y, x = Grid(ns, dx).axes(device=device)
    if system.lenslet_shape == "circle":
        return aperture_coverage("circle", x[None, :], y[:, None], aperture, (dx, dx), antialias=True)
    return aperture_coverage("square", x, x.new_zeros(()), aperture, (dx, dx), antialias=True)


def _row_transform(transform: torch.Tensor, region: torch.Tensor, tiles: int) -> torch.Tensor:
    """``T @`` every tile row of ``region (tiles ns, W)`` in one GEMM: ``(3, p, tiles, W)``,
    window block, output row within it, tile row, column (``T`` is ``(3 p, ns)``)."""
    ns = transform.shape[1]
    width = region.shape[-1]
    rows = transform @ region.reshape(tiles, ns, width).permute(1, 0, 2).reshape(ns, -1)
    return rows.reshape(3, -1, tiles, width)


def _column_transform(transform: torch.Tensor, rows: torch.Tensor, lit: torch.Tensor) -> torch.Tensor:
    """The sensor canvas ``(C, C)``, ``C = (tiles + 2) p``, from row-transformed tiles ``rows``
    ``(3, p, tiles, tiles ns)`` (:func:`_row_transform`) of the lenslets ``lit (tiles, tiles)``
    (the others are zeroed as they are added: exact, the row transform keeps tiles apart).

    The canvas is ``Tb @ region @ Tb.T`` with the block-banded ``Tb`` (``T`` in every tile
    row). Tile row ``i``'s window block ``k`` lands on canvas block ``i + k``: the row
    outputs are overlap-added down the canvas first, then every ``(p, ns)`` block of that
    ``(C, tiles ns)`` strip that holds light (canvas block ``r``, tile column ``j``: a lit
    lenslet in rows ``r - 2 .. r`` of column ``j``) goes through ``@ T.T`` (one batched GEMM)
    and is overlap-added across. Adding lenslets *before* the column transform (the larger
    one, ``3 p > ns``) does it once per canvas row instead of once per lenslet row:
    ``(2 reach + 3) / (3 (2 reach + 1))`` of a per-lenslet evaluation's work (0.39 at
    reach 5), and no per-lenslet window stack; the dark blocks skipped save another
    5-35 % at reach 3-6 of the 10x/0.3 system.
    """
    ns = transform.shape[1]
    per_lenslet = rows.shape[1]
    tiles = lit.shape[0]
    strip = rows.new_zeros((tiles + 2, per_lenslet, tiles * ns))
    active = torch.zeros((tiles + 2, tiles), dtype=torch.bool, device=lit.device)
    mask = lit.repeat_interleave(ns, 1)[:, None, :].to(rows.dtype)  # unlit lenslets zeroed here
    for block in range(3):  # window block ``block`` of tile row i lands on canvas block i + block
        strip[block : block + tiles].addcmul_(rows[block].permute(1, 0, 2), mask)
        active[block : block + tiles] |= lit
    r, j = active.nonzero(as_tuple=True)
    blocks = strip.reshape(tiles + 2, per_lenslet, tiles, ns)[r, :, j]  # (blocks, p, ns)
    cols = rows.new_zeros((tiles + 2, tiles, per_lenslet, 3, per_lenslet))  # dark blocks stay zero
    cols[r, j] = (blocks @ transform.T).reshape(-1, per_lenslet, 3, per_lenslet)
    field = rows.new_zeros((tiles + 2, per_lenslet, tiles + 2, per_lenslet))
    for block in range(3):  # window block ``block`` of tile column j lands on canvas block j + block
        field[:, :, block : block + tiles] += cols[:, :, :, block].transpose(1, 2)
    canvas = (tiles + 2) * per_lenslet
    return field.reshape(canvas, canvas)


def _bin(power: torch.Tensor, factor: int) -> torch.Tensor:
    """Sum ``factor x factor`` blocks (sub-samples centred in each pixel: midpoint rule)."""
    z, ny, nx = power.shape
    return power.reshape(z, ny // factor, factor, nx // factor, factor).sum(dim=(2, 4))


def _expand_symmetric(unique: dict[tuple[int, int], torch.Tensor], s: int) -> torch.Tensor:
    """All ``S x S`` sub-positions from the ``0 <= a <= b`` ones by mirrors and transposes."""
    half = s // 2
    rows = []
    for a in range(-half, half + 1):
        row = []
        for b in range(-half, half + 1):
            lo, hi = sorted((abs(a), abs(b)))
            pattern = unique[(lo, hi)]
            if abs(a) > abs(b):
                pattern = pattern.transpose(-2, -1)
            if a < 0:
                pattern = pattern.flip(-2)
            if b < 0:
                pattern = pattern.flip(-1)
            row.append(pattern)
        rows.append(torch.stack(row, dim=1))
    return torch.stack(rows, dim=1)
