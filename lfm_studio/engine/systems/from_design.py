"""Build engine systems and accuracy settings from a validated :class:`Design`.

The one place where the user-facing spec (units in key names) meets the engine's SI
objects; each spec already converts its own units (``spec.focal_length`` in metres).

Which accuracy knob (:class:`AccuracySpec`) reaches which computation:

==================  ==========================================  ==========================================
knob                Fourier LFM (:class:`FourierAccuracy`)      conventional LFM (:class:`ConventionalAccuracy`)
==================  ==========================================  ==========================================
propagator          full-field path only                        n/a: always the Fresnel transfer function of
                                                                the whole lenslet region on one FFT grid
oversampling        sub-samples per pixel                       sensor-field sub-samples per pixel: ``2^o + 1``
                                                                (midpoint rule); for the exact ("fourier")
                                                                integral 1.4 (o <= 2) or 2.8 (o = 3) samples
                                                                per intensity Nyquist interval; NIP grid
                                                                factor ``clip(o, 1, 1.5)``
pixel_integration   exact box integral ("fourier") or the       the same two methods on the sensor-field
                    sub-sample sum ("midpoint")                 sub-samples (:class:`LatticeTransform`)
padding             full-field propagation padding               n/a: fixed (canvas + >= half a pitch a side)
dtype               field precision                             field precision
debye_points        n/a: the pupil-plane field is closed-form   not used: the engine's converged order for the
                    (exact defocus phase, no quadrature)        phase excursion (fixed counts: 41-127 % error)
objective_model     pupil field model                           NIP field model (Debye / paraxial)
per_lenslet         "auto" (per lenslet unless sub-images       n/a: lenslets are always summed coherently
                    overlap) or the full sensor field           on one sensor grid
depth_chunk         depths per FFT batch (per-lenslet path)     depths per Debye NIP-field batch
voxels_per_lenslet  n/a                                         lateral voxels per lenslet pitch (odd)
volume_oversampling volume voxels per sensor pixel ``k``: the   n/a
                    PSF on a k-times finer virtual sensor
                    (:func:`fourier_system_of` ``refine``)
==================  ==========================================  ==========================================
"""

from __future__ import annotations

from lfm_studio.engine.design import Design, RegularMLASpec
from lfm_studio.engine.dtypes import real_dtype_named
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.systems.conventional_patterns import OUTPUT_OVERSAMPLING
from lfm_studio.engine.systems.conventional_psf import ConventionalAccuracy
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem
from lfm_studio.engine.systems.fourier_psf import FourierAccuracy
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem


def objective_of(design: Design) -> ObjectiveLens:
    """The engine objective of ``design``."""
    spec = design.objective
    return ObjectiveLens(
        spec.magnification, spec.numerical_aperture, spec.immersion_index, spec.tube_lens_focal_length
    )


def microlens_array_of(design: Design) -> MicrolensArray:
    """The engine MLA of ``design`` (lenslet centres in MLA-plane metres)."""
    lenslets = tuple(
        Lenslet(lens.center, lens.aperture_diameter, lens.focal_length, lens.shape)
        for lens in design.mla.lenslets
    )
    return MicrolensArray(lenslets)


def virtual_pixel_count(pixels: int, refine: int) -> int:
    """Virtual pixels along an axis of ``pixels`` camera pixels split ``refine`` (odd) times:
    ``refine * pixels``, plus ``refine - 1`` on an even axis so that the axis pixel is the
    centre of its block (blocks ``[k i, k i + k)``; the extra ones are dropped when binning)."""
    return refine * pixels + (refine - 1) * (1 - pixels % 2)


def fourier_system_of(design: Design, *, refine: int = 1) -> FourierLFMSystem:
    """The Fourier LFM described by ``design`` (``kind == "fourier"``).

    ``refine`` ``k`` (odd) splits each camera pixel into ``k x k`` virtual pixels (pitch /
    k): the PSF sampling of a volume ``k`` times finer than pixel / M_T
    (``accuracy.volume_oversampling``). The virtual sensor has ``k n`` pixels per axis of
    ``n`` (``k n + k - 1`` when ``n`` is even, so that the axis pixel sits at the centre of
    its block); summing the blocks ``[k i, k i + k)`` gives the camera's PSF
    (:class:`~lfm_studio.engine.operators.binned.BinnedProjector`).
    """
    if design.kind != "fourier":
        raise ValueError(f"design kind must be 'fourier' for a Fourier LFM; got {design.kind!r}.")
    if not (isinstance(refine, int) and refine >= 1 and refine % 2 == 1):
        raise ValueError(
            f"refine must be an odd integer >= 1 (virtual pixels per camera pixel); got {refine!r}."
        )
    if design.relay is None:
        raise ValueError("a Fourier LFM needs a relay (Fourier) lens; the design has relay None.")
    ny, nx = design.camera.pixel_count
    return FourierLFMSystem(
        objective=objective_of(design),
        fourier_focal_length=design.relay.focal_length,
        mla=microlens_array_of(design),
        mla_to_camera=design.mla_to_camera_distance,
        pixel_pitch=design.camera.pixel_pitch / refine,
        sensor_shape=(virtual_pixel_count(ny, refine), virtual_pixel_count(nx, refine)),
        wavelength=design.wavelength,
        pupil_zernike_waves=design.pupil_phase.terms if design.pupil_phase is not None else (),
    )


def fourier_accuracy_of(design: Design) -> FourierAccuracy:
    """The Fourier-LFM accuracy knobs of ``design.accuracy``."""
    spec = design.accuracy
    return FourierAccuracy(
        oversampling=max(1, int(spec.oversampling)),
        model=spec.objective_model,
        dtype=real_dtype_named(spec.dtype),
        method="auto" if spec.per_lenslet else "full_field",
        depth_chunk=spec.depth_chunk,
        propagator=spec.propagator,
        padding=float(spec.padding),
        pixel_integration=spec.pixel_integration,
    )


def conventional_accuracy_of(
    design: Design, system: ConventionalLFMSystem | None = None
) -> ConventionalAccuracy:
    """The conventional-LFM accuracy knobs of ``design.accuracy`` (see the module table).

    ``oversampling`` ``o`` gives the sensor-field sub-samples per rectified pixel (odd, one on
    the pixel centre): with ``pixel_integration`` ``"midpoint"`` ``2^o + 1`` (3, 5, 9 for
    o = 1, 2, 3); with ``"fourier"`` (the presets) the sub-samples of ``pixel_oversampling`` 1.4
    (the engine's default, o <= 2) or 2.8 (o = 3) per intensity Nyquist interval
    (:func:`sub_samples`: 3 and 5 on the shipped 10x/0.3 and Prevedel designs): the exact box
    integral at 3 sub-samples per pixel is more accurate than the midpoint rule at 5 there
    (docs/benchmarks.md), and the count follows the system's band, not its pixel. The NIP grid factor
    is ``clip(o, 1, 1.5)`` (1 for preview; 1.5 for standard and reference: it cut the standard
    preset's error by 40 % for 1.2-1.3x the time, docs/benchmarks.md).
    """
    spec = design.accuracy
    system = system or conventional_system_of(design)  # (the caller's, when it has built it)
    # sub_samples() counts ceil(pixel * pixel_oversampling / nyquist), made odd: aim inside the bin.
    nyquist_per_pixel = system.wavelength * system.mla_to_camera / (2.0 * system.pitch) / system.pixel_size
    if spec.pixel_integration == "midpoint":
        pixel_oversampling = (2 ** int(spec.oversampling) + 1 - 0.5) * nyquist_per_pixel
    else:
        pixel_oversampling = OUTPUT_OVERSAMPLING * max(1, 2 ** (int(spec.oversampling) - 2))
    return ConventionalAccuracy(
        dtype=real_dtype_named(spec.dtype),
        model=spec.objective_model,
        debye_points=None,
        pixel_oversampling=pixel_oversampling,
        pixel_integration=spec.pixel_integration,
        nip_oversampling=max(1.0, min(1.5, float(spec.oversampling))),
        depth_chunk=spec.depth_chunk,
    )


def conventional_system_of(
    design: Design,
    *,
    lenslets: tuple[int, int] | None = None,
    pixels_per_lenslet: int | None = None,
    voxels_per_lenslet: int | None = None,
) -> ConventionalLFMSystem:
    """The conventional LFM described by ``design`` (``kind == "conventional"``).

    Parameters
    ----------
    lenslets : lenslets imaged, ``(ny, nx)``; default: those the sensor covers (at most the array).
    pixels_per_lenslet : rectified pixels per lenslet (odd); default: pitch / pixel pitch
        rounded to the nearest odd integer.
    voxels_per_lenslet : lateral super-sampling of the volume (odd); default:
        ``design.accuracy.voxels_per_lenslet`` (5 unless the design sets it).

    The lenslets' clear aperture is ``mla.lenslet_aperture_diameter_um`` (``None``: the pitch);
    ``pupil_phase`` (rotationally symmetric terms only) becomes ``pupil_zernike_waves``.
    """
    if design.kind != "conventional":
        raise ValueError(f"design kind must be 'conventional' for a conventional LFM; got {design.kind!r}.")
    mla = design.mla
    if not isinstance(mla, RegularMLASpec) or mla.lattice != "square":
        raise ValueError(
            "conventional LFM needs a regular square MLA (layout 'regular', lattice 'square'); "
            f"got layout {mla.layout!r}, lattice {getattr(mla, 'lattice', None)!r}. "
            "Fix: use MLASpec square_grid / a RegularMLASpec with lattice 'square'."
        )
    pitch_m = mla.pitch_um * 1e-6
    camera = design.camera
    if voxels_per_lenslet is None:
        voxels_per_lenslet = design.accuracy.voxels_per_lenslet
    if pixels_per_lenslet is None:
        ratio = pitch_m / camera.pixel_pitch
        pixels_per_lenslet = max(1, 2 * round((ratio - 1) / 2) + 1)
    if lenslets is None:
        ny = min(mla.shape[0], int(camera.pixel_count[0] * camera.pixel_pitch / pitch_m))
        nx = min(mla.shape[1], int(camera.pixel_count[1] * camera.pixel_pitch / pitch_m))
        lenslets = (max(1, ny), max(1, nx))
    return ConventionalLFMSystem(
        objective=objective_of(design),
        pitch=pitch_m,
        lenslet_focal_length=mla.focal_length_mm * 1e-3,
        lenslet_shape=mla.lenslet_shape,
        mla_to_camera=design.mla_to_camera_distance,
        lenslets=lenslets,
        pixels_per_lenslet=pixels_per_lenslet,
        voxels_per_lenslet=voxels_per_lenslet,
        wavelength=design.wavelength,
        lenslet_aperture=None if mla.lenslet_aperture_diameter_um is None else mla.lenslet_aperture_um * 1e-6,
        pupil_zernike_waves=design.pupil_phase.terms if design.pupil_phase is not None else (),
    )
