"""Light-field patterns of a conventional LFM: one sensor pattern per depth and voxel sub-position.

For a point at depth ``z`` on the lenslet axis, the native-image-plane (NIP) field is
the image-side Debye field (:func:`debye_psf`), computed once for all depths on a grid
of ``Ns`` samples per lenslet pitch (``Ns`` a multiple of ``voxels_per_lenslet``), so a
voxel ``a`` sub-positions off axis is the same field shifted by ``a Ns / S`` samples.

Every lenslet within the light's reach multiplies its ``Ns x Ns`` patch by its lens phase, and
the whole lenslet region goes to the sensor at once by the Fresnel transfer function
``exp(-j pi lambda d (fx^2 + fy^2))`` on a periodic FFT grid (:class:`LatticeTransform`), so the
lenslets' fields add as *complex fields*: a lenslet's light interferes with its neighbours'
diffraction tails, and adding intensities instead is off by 5-10 % at defocus (measured
against a full-field simulation; tests). The inverse transform lands on the sensor's sub-pixel
centres (a band-limited resampling when the NIP grid is not the sub-sample grid), and
``|U|^2`` is integrated on the rectified pixels (the midpoint rule on the sub-samples, or the
exact box integral of the sampled intensity in Fourier space: ``pixel_integration``). Both the
lens phase and the transfer function are separable, so the transform is a row pass and a column
pass of 1-D FFTs.

A lenslet's clear aperture (``system.lenslet_aperture``, default the pitch) is applied to its
patch as an antialiased coverage; the grid is planned from the pitch whatever the aperture.

Gradients: ``lenslet_focal_length``, ``mla_to_camera``, ``wavelength`` and ``lenslet_aperture``
may be given as 0-d tensors that override the system's floats in the physics (the lens and
Fresnel phases, the Debye integrand, the aperture coverage) while every discrete choice
(sample counts, grids, reach) stays planned from the system's floats; a tensor
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
from lfm_studio.engine.optics.phase_kernels import aperture_coverage, lens_phase, unit_phasor, wavenumber
from lfm_studio.engine.optics.pixel_integration import check_pixel_integration, integrate_pixels
from lfm_studio.engine.progress import CancelToken, ProgressCallback, checkpoint
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem

DEBYE_DEPTHS = 4  # depths per Debye evaluation of the NIP fields (bounds its temporaries)
Scalar = float | torch.Tensor
OUTPUT_OVERSAMPLING = 1.4  # sensor-field samples per Nyquist interval of the sub-image intensity


def samples_per_pitch(system: ConventionalLFMSystem, oversampling: float = 1.0) -> int:
    """NIP samples per pitch ``Ns``: a multiple of ``S`` (odd), at Nyquist for the image-side NA,
    and ``Ns > 3 P^2 / (lambda d)``, times ``oversampling`` (>= 1).

    The second bound comes from the three-pitch matrix transform this grid was first planned for
    (its sampled Fresnel sum repeats every ``lambda d / dx``); it is kept, so the grids (and the
    presets' measured errors) did not move with the FFT transform. It also covers what the
    transfer function needs, the lens phase's local frequency plus the NIP field's band,
    ``Ns >= P^2 / (lambda f) + 2 P NA_img / lambda`` (30 against 48 for the 10x/0.3 system).
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
    shared by the depths of a call). ``radial_sampling`` (an integer ``s``) sets the radial table's
    step to ``min(dx, lambda / (4 NA_img)) / s``: ``s`` entries per grid step or per Nyquist step
    of the field, whichever is finer (8: interpolation error <= (k NA h)^4 / 384 ~ 4e-6 of the
    peak, :func:`debye_psf`; the NIP grids are finer than Nyquist, 1.7 um against 4.4 um for the
    10x/0.3 system at the standard preset, and 8 entries per grid step cost 2x the Bessel
    evaluations for a 16x smaller error bound); ``"exact"`` or ``"auto"`` are passed on;
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
    table = radial_table_sampling(system, dx, radial_sampling)
    out = torch.empty((len(depths), h + 1, h + 1), dtype=cdtype, device=device)
    # Without a pupil phase the defocus phase is odd in z and the rest real: U(-z) = -conj(U(z))
    # (exact), so of a pair +-z only one is integrated.
    mirror: dict[int, int] = {}
    if waves is None:
        first: dict[float, int] = {}
        for index, depth in enumerate(depths):
            if -depth in first and depth != 0.0:
                mirror[index] = first[-depth]
            else:
                first.setdefault(depth, index)
    computed = [index for index in range(len(depths)) if index not in mirror]
    # A few depths per Debye call: its interpolation temporaries are complex128 per depth and
    # sample (about 15x the complex64 result), so one call for 31 depths on a 518^2 quadrant
    # peaked at 490 MB above the result; the radial tables are per depth anyway.
    for start in range(0, len(computed), DEBYE_DEPTHS):
        part = torch.tensor(computed[start : start + DEBYE_DEPTHS], device=device)
        field = debye_psf(
            system.objective, quadrant, lam, z[part], position=(offset, offset),
            image_side=True, radial_sampling=table, model=model, n_quadrature=n_quadrature,
            dtype=cdtype, device=device, zernike_waves=waves,
        )  # fmt: skip
        out[part] = field.data.reshape(-1, h + 1, h + 1)
    for index, source in mirror.items():
        out[index] = -out[source].conj()
    return out


def radial_table_sampling(system: ConventionalLFMSystem, dx: float, radial_sampling: int | str) -> int | str:
    """The ``radial_sampling`` :func:`debye_psf` gets for NIP grid step ``dx`` (see :func:`nip_quadrants`):
    an integer ``s`` becomes ``ceil(s dx / (lambda / (4 NA_img)))`` when ``dx`` is finer than that
    Nyquist step (the table step is then ``<=`` Nyquist / ``s``); anything else is passed on."""
    if isinstance(radial_sampling, bool) or not isinstance(radial_sampling, int) or radial_sampling < 1:
        return radial_sampling
    na_image = _value(system.objective.numerical_aperture) / system.magnification
    nyquist = system.wavelength / (4.0 * na_image)
    return max(1, math.ceil(radial_sampling * dx / nyquist - 1e-9)) if dx < nyquist else radial_sampling


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
    before the pixel integration (midpoint rule or exact box integral; convergence studies in the tests).
    """
    nyquist = system.wavelength * system.mla_to_camera / (2.0 * system.pitch)
    count = math.ceil(system.pixel_size * oversampling / nyquist)
    return count + 1 - count % 2


def fft_pitches(reach: int) -> int:
    """Pitches per side of the periodic FFT grid at ``reach``: the canvas ``2 reach + 3`` and at least half
    a pitch of zero padding on each side, rounded up to a 5-smooth count (fast FFT lengths).

    Light that leaves the canvas wraps around: it re-enters only ``2.5`` pitches or more beyond the
    outermost lenslet's axis (the matrix form it replaced cut each lenslet's light at 1.5 pitches).
    """
    count = 2 * reach + 4
    while True:
        rest = count
        for prime in (2, 3, 5):
            while rest % prime == 0:
                rest //= prime
        if rest == 1:
            return count
        count += 1


def _fresnel_transfer(
    n_in: int, dx: float, shift: float, lam: Scalar, d: Scalar, cdtype: torch.dtype, device: torch.device
) -> torch.Tensor:
    """``exp(-j pi lambda d f^2 + j 2 pi f shift)`` on the ``n_in`` DFT frequencies of spacing ``dx``:
    the 1-D Fresnel transfer function (constant ``exp(j k d)`` dropped) with the output moved by
    ``-shift`` (so the first output sample is the canvas's first)."""
    f = torch.fft.fftfreq(n_in, dx, dtype=torch.float64, device=device)
    phase = (-math.pi * lam * d) * (f * f) + (2.0 * math.pi * shift) * f
    return unit_phasor(phase, cdtype)


def _propagate(x: torch.Tensor, transfer: torch.Tensor, n_out: int, canvas: int) -> torch.Tensor:
    """Fresnel propagation of ``x`` along its last axis: zero-padded DFT of length ``len(transfer)``,
    times ``transfer`` (:func:`_fresnel_transfer`, with the factor ``n_out / len(transfer)`` of a
    resampling folded in), inverse DFT of length ``n_out``, first ``canvas`` samples.

    When the lengths differ, the frequencies common to both (``|k| <= (min - 1) // 2``) are carried
    across and the rest of the ``n_out`` spectrum is zero: a band-limited resampling. The two
    blocks of common frequencies are multiplied straight into the new spectrum (an index gather
    and scatter of the same copy took 0.45 s of a 3 s build)."""
    n_in = transfer.shape[0]
    spectrum = torch.fft.fft(x, n=n_in, dim=-1)
    if n_in == n_out:
        return torch.fft.ifft(_times(spectrum, transfer), dim=-1).narrow(-1, 0, canvas)
    half = (min(n_in, n_out) - 1) // 2
    low, high = slice(0, half + 1), slice(n_in - half, n_in)
    if torch.is_grad_enabled() and (spectrum.requires_grad or transfer.requires_grad):
        gap = spectrum.new_zeros((*spectrum.shape[:-1], n_out - 2 * half - 1))
        parts = (spectrum[..., low] * transfer[low], gap, spectrum[..., high] * transfer[high])
        resampled = torch.cat(parts, dim=-1)
    else:
        resampled = spectrum.new_empty((*spectrum.shape[:-1], n_out))
        torch.mul(spectrum[..., low], transfer[low], out=resampled[..., : half + 1])
        resampled[..., half + 1 : n_out - half].zero_()
        torch.mul(spectrum[..., high], transfer[high], out=resampled[..., n_out - half :])
    del spectrum
    return torch.fft.ifft(resampled, dim=-1).narrow(-1, 0, canvas)


def _times(x: torch.Tensor, factor: torch.Tensor | float) -> torch.Tensor:
    """``x * factor``, in place (``x`` is a temporary) unless autograd needs the operands."""
    if torch.is_grad_enabled() and (
        x.requires_grad or (isinstance(factor, torch.Tensor) and factor.requires_grad)
    ):
        return x * factor
    return x.mul_(factor)


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
    pixel_integration: str = "midpoint",
    lenslet_focal_length: Scalar | None = None,
    mla_to_camera: Scalar | None = None,
    wavelength: Scalar | None = None,
    lenslet_aperture: Scalar | None = None,
    zernike_waves: Mapping[int, Scalar] | None = None,
    out: torch.Tensor | None = None,
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
    nip_oversampling, pixel_oversampling : accuracy knobs: the NIP grid factor
        (:func:`samples_per_pitch`) and the sensor-field samples per intensity Nyquist interval
        (:func:`sub_samples`).
    pixel_integration : ``"midpoint"`` (the sum of each pixel's ``m x m`` sub-samples, error
        ``~ 1/m^2``) or ``"fourier"`` (the exact box integral of the sampled intensity,
        :func:`~lfm_studio.engine.optics.pixel_integration.integrate_pixels`; exact once the
        intensity is sampled without aliasing).
    lenslet_focal_length, mla_to_camera : optional 0-d tensors (metres) overriding the
        system's values in the lens phase and the Fresnel transfer function, for gradients; the
        sampling is planned from the system's floats, so pass a system holding the same values.
    wavelength : optional 0-d tensor (metres) overriding ``system.wavelength`` in the
        physics: the Debye integrand of the NIP field (when computed here; a given
        ``nip_field`` must carry its own), the lens phase and the transfer function. Sample
        counts, grids and the lenslet reach stay planned from ``system.wavelength``.
    lenslet_aperture : optional 0-d tensor (metres, ``<= pitch``) overriding
        ``system.lenslet_aperture`` (the clear aperture's side or diameter); it enters through
        the antialiased aperture coverage of the NIP samples (:func:`lenslet_aperture_weights`),
        the grid stays planned from the pitch. The NA reaches
        the patterns through the NIP field (a tensor NA in ``system.objective``, or a
        ``nip_field`` that carries a graph: :func:`debye_psf` is differentiable in it).
    zernike_waves : optional ``{noll index: waves}`` (floats or 0-d tensors, ``m = 0`` terms)
        overriding or adding terms of ``system.pupil_zernike_waves`` in the Debye integrand of the
        NIP field (when computed here; a given ``nip_field`` carries its own mask).
    out : optional ``(S, S, Z, H, H)`` tensor (a view is fine) the patterns are written into, in
        place of a new ``(Z, S, S, H, H)`` result (no intermediate stacks).

    Returns
    -------
    Tensor ``(Z, S, S, H, H)``, ``H = (2 reach + 3) Q``: power per rectified pixel of a
    unit-power emitter at each depth and voxel sub-position ``(row, col)``, in NIP
    (image) orientation, the canvas centred on the source lenslet's centre. With ``out``
    the same values are in ``out`` ``(S, S, Z, H, H)``, which is returned.
    """
    s, q = system.voxels_per_lenslet, system.pixels_per_lenslet
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
    h = (2 * reach + 3) * q
    if out is None:
        result = torch.zeros((s, s, len(depths), h, h), dtype=dtype, device=base.device)
    elif tuple(out.shape) != (s, s, len(depths), h, h):
        raise ValueError(f"out has shape {tuple(out.shape)}; expected {(s, s, len(depths), h, h)}.")
    else:
        result = out
    lattice = LatticeTransform(
        system, reach, dtype=dtype, device=base.device, oversampling=pixel_oversampling,
        pixel_integration=pixel_integration,
        nip_oversampling=nip_oversampling, lenslet_focal_length=lenslet_focal_length,
        mla_to_camera=mla_to_camera, wavelength=wavelength, lenslet_aperture=lenslet_aperture,
    )  # fmt: skip
    offsets = _unique_offsets(s // 2)
    for z in range(base.shape[0]):
        checkpoint(cancel, progress, z, base.shape[0], f"patterns of depth {z + 1}/{base.shape[0]}")
        found = lattice.patterns(base[z], offsets)
        for (a, b), pattern in zip(offsets, found, strict=True):
            _place_symmetric(result, z, a, b, pattern)
    checkpoint(cancel, progress, base.shape[0], base.shape[0], "patterns done")
    return result if out is not None else result.permute(2, 0, 1, 3, 4)


def offset_pattern(
    system: ConventionalLFMSystem,
    base: torch.Tensor,
    a: int,
    b: int,
    *,
    reach: int,
    dtype: torch.dtype,
    oversampling: float = OUTPUT_OVERSAMPLING,
    nip_oversampling: float = 1.0,
    pixel_integration: str = "midpoint",
    lenslet_focal_length: Scalar | None = None,
    mla_to_camera: Scalar | None = None,
    wavelength: Scalar | None = None,
    lenslet_aperture: Scalar | None = None,
) -> torch.Tensor:
    """Pattern ``(Z, H, H)`` of a source ``a`` sub-positions below and ``b`` right of the lenslet axis
    (any signs: the lattice transform of :class:`LatticeTransform`, no symmetry used).

    ``base`` is the on-axis NIP field ``(Z, N, N)`` with ``N = nip_field_size(system, reach)``.
    ``oversampling``: the sensor-field samples per intensity Nyquist interval (:func:`sub_samples`);
    ``nip_oversampling``: the NIP grid factor ``base`` was computed with (:func:`nip_fields`);
    ``pixel_integration``: as for :func:`conventional_patterns`;
    ``lenslet_focal_length``, ``mla_to_camera``, ``wavelength``, ``lenslet_aperture``: tensor
    overrides for gradients (:func:`conventional_patterns`).
    """
    lattice = LatticeTransform(
        system, reach, dtype=dtype, device=base.device, oversampling=oversampling,
        pixel_integration=pixel_integration,
        nip_oversampling=nip_oversampling, lenslet_focal_length=lenslet_focal_length,
        mla_to_camera=mla_to_camera, wavelength=wavelength, lenslet_aperture=lenslet_aperture,
    )  # fmt: skip
    return torch.stack([lattice.patterns(base[z], [(a, b)])[0] for z in range(base.shape[0])])


class LatticeTransform:
    """The lenslet lattice's Fresnel transform at one reach: NIP field -> sensor patterns.

    Every lenslet within ``reach`` of the source's lenslet multiplies its ``Ns x Ns`` patch of
    the NIP field by its lens phase ``exp(-j k (x^2 + y^2) / 2f)`` (and the clear aperture's
    antialiased coverage), and the whole lenslet region is carried to the sensor at once by the
    Fresnel transfer function ``exp(-j pi lambda d (fx^2 + fy^2))`` on a periodic grid of
    :func:`fft_pitches` pitches: the lenslets' fields add coherently on the sensor by
    construction. The inverse DFT has ``Q m`` samples per pitch (the sensor sub-samples: a
    band-limited resampling when ``Ns != Q m``, exact when they are equal), ``|U|^2`` is
    integrated on the pixels (``pixel_integration``: the midpoint rule on the ``m x m``
    sub-samples, :func:`sub_samples`, or the exact box integral of the sampled intensity).

    Both the lens phase and the transfer function are separable, so the 2-D transform is a
    1-D transform along the rows and one along the columns. Square lenslets: the sources
    ``(a, b)`` with the same column offset ``b`` share the row pass (it acts on each NIP row
    alone; each ``a`` crops its rows from it), so the 6 sub-positions of ``S = 5`` take 3 row
    passes and 6 column passes. Round lenslets: the disk is not separable; each source is
    transformed alone.
    """

    def __init__(
        self,
        system: ConventionalLFMSystem,
        reach: int,
        *,
        dtype: torch.dtype,
        device: torch.device | str = "cpu",
        oversampling: float = OUTPUT_OVERSAMPLING,
        pixel_integration: str = "midpoint",
        nip_oversampling: float = 1.0,
        lenslet_focal_length: Scalar | None = None,
        mla_to_camera: Scalar | None = None,
        wavelength: Scalar | None = None,
        lenslet_aperture: Scalar | None = None,
    ) -> None:
        self.system, self.reach, self.dtype = system, reach, dtype
        self.pixel_integration = check_pixel_integration(pixel_integration)
        self.cdtype = torch.complex64 if dtype == torch.float32 else torch.complex128
        self.m = sub_samples(system, oversampling)
        self.ns = ns = samples_per_pitch(system, nip_oversampling)
        q = system.pixels_per_lenslet
        self.step = ns // system.voxels_per_lenslet
        self.span = (2 * reach + 1) * ns  # the lenslet region, NIP samples per side
        pitches = fft_pitches(reach)
        self.n_out = pitches * q * self.m
        self.canvas = (2 * reach + 3) * q * self.m  # sensor sub-samples per side
        dx, self.out_step = system.pitch / ns, system.pitch / (q * self.m)
        device = torch.device(device)
        lam = system.wavelength if wavelength is None else wavelength
        d = system.mla_to_camera if mla_to_camera is None else mla_to_camera
        f = system.lenslet_focal_length if lenslet_focal_length is None else lenslet_focal_length
        # The region's sample 0 sits (span // 2) dx before the source lenslet's axis, the canvas's
        # first sample (canvas // 2) out_step before it: the transfer function moves the output.
        shift = (self.span // 2) * dx - (self.canvas // 2) * self.out_step
        self.transfer = _fresnel_transfer(pitches * ns, dx, shift, lam, d, self.cdtype, device)
        if self.n_out != pitches * ns:  # the resampling's factor, applied once with the transfer
            self.transfer = self.transfer * (self.n_out / (pitches * ns))
        x = (torch.arange(ns, dtype=torch.float64, device=device) - ns // 2) * dx
        lens = unit_phasor(lens_phase(x, 0.0, f, wavenumber(lam)), self.cdtype)  # per axis
        aperture = system.lenslet_aperture if lenslet_aperture is None else lenslet_aperture
        tiles = 2 * reach + 1
        self.disk: torch.Tensor | None = None
        if system.lenslet_shape == "circle":
            diameter = system.pitch if aperture is None else aperture
            disk = lenslet_aperture_weights(system, ns, diameter, device).to(self.cdtype)
            self.disk = disk.repeat(tiles, tiles)
        elif aperture is not None:  # the separable square aperture on both axes
            lens = lens * lenslet_aperture_weights(system, ns, aperture, device).to(self.cdtype)
        self.weights = lens.repeat(tiles)  # (span,): every lenslet's phase (and square aperture)

    def _rows(self, region: torch.Tensor) -> torch.Tensor:
        """Row pass: each row of ``region (..., span)`` weighted and carried to the sensor columns."""
        return _propagate(region * self.weights, self.transfer, self.n_out, self.canvas)

    def _columns(self, rows: torch.Tensor) -> torch.Tensor:
        """Column pass and pixels: ``rows (span, canvas)`` -> pattern ``(H, H)``. The pass runs on the
        transpose (a contiguous copy: a padded DFT along the strided axis took 3x as long)."""
        if torch.is_grad_enabled() and (rows.requires_grad or self.weights.requires_grad):
            columns = (rows.mT * self.weights).contiguous()  # out= does not record a graph
        else:
            columns = rows.new_empty(rows.mT.shape)  # contiguous: the weighted copy is one pass
            torch.mul(rows.mT, self.weights, out=columns)
        field = _propagate(columns, self.transfer, self.n_out, self.canvas)  # U^T
        power = field.real**2 + field.imag**2
        del field
        # The canvas is dark at its edges, so the exact integral's periodic box filter is the pixels'.
        pixels = integrate_pixels(power, self.m, self.pixel_integration)
        return (pixels * (self.out_step * self.out_step)).mT.to(self.dtype)

    def patterns(self, field: torch.Tensor, offsets: list[tuple[int, int]]) -> list[torch.Tensor]:
        """Patterns ``(H, H)`` of the sources ``offsets`` ``[(a, b), ...]`` (sub-positions below and
        right of the axis) from one depth's on-axis NIP field ``(N, N)``."""
        n, span, step, ns = field.shape[-1], self.span, self.step, self.ns

        def first(offset: int) -> int:  # the region of lenslets -reach..reach around a source
            return n // 2 - offset * step - self.reach * ns - ns // 2

        found: dict[tuple[int, int], torch.Tensor] = {}
        for b in sorted({b for _, b in offsets}):
            left = first(b)
            rows_a = sorted({a for a, bb in offsets if bb == b})
            if self.disk is None:  # square lenslets: one row pass for every a of this b
                top, bottom = min(first(a) for a in rows_a), max(first(a) for a in rows_a) + span
                region = field[top:bottom, left : left + span].to(self.cdtype)
                rows = self._rows(region)
                for a in rows_a:  # one column pass at a time: its temporaries are the largest
                    found[(a, b)] = self._columns(rows[first(a) - top : first(a) - top + span])
            else:
                for a in rows_a:
                    region = field[first(a) : first(a) + span, left : left + span].to(self.cdtype)
                    found[(a, b)] = self._columns(self._rows(region * self.disk))
        return [found[offset] for offset in offsets]


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


def _place_symmetric(out: torch.Tensor, z: int, a: int, b: int, pattern: torch.Tensor) -> None:
    """Write the pattern of sub-position ``(a, b)`` (``0 <= a <= b``) into ``out (S, S, Z, H, H)`` at
    every sub-position it maps to by the lattice's x / y mirrors and the transpose."""
    half = out.shape[0] // 2
    for row in {a, -a}:
        for col in {b, -b}:
            targets = [(row, col, False)] + ([(col, row, True)] if a != b else [])
            for r, c, transposed in targets:
                image = pattern.transpose(-2, -1) if transposed else pattern
                if r < 0:
                    image = image.flip(-2)
                if c < 0:
                    image = image.flip(-1)
                out[r + half, c + half, z] = image
