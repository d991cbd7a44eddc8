"""The knob settings the sweep evaluates, the converged reference, and the presets as points.

Every setting is the "standard" preset's engine options with ONE knob changed (so a
row shows what that knob costs and buys), plus one point per accuracy preset. Knobs
that do not reach a system kind's computation are left out of its sweep (the reason
is in ``NOT_APPLICABLE``). Engine-only knobs that :class:`AccuracySpec` does not
expose (the per-lenslet window margin, the conventional NIP grid factor and
radial table) are swept too, since the presets rely on their defaults.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch

from lfm_studio.bench.cases import BenchCase
from lfm_studio.engine.design import ACCURACY_PRESETS, AccuracySpec
from lfm_studio.engine.design.evolve import evolve
from lfm_studio.engine.systems.conventional_psf import ConventionalAccuracy
from lfm_studio.engine.systems.fourier_psf import FourierAccuracy
from lfm_studio.engine.systems.from_design import conventional_accuracy_of, fourier_accuracy_of
from lfm_studio.engine.systems.kinds import CONVENTIONAL, FOURIER, SystemKind

EngineOptions = FourierAccuracy | ConventionalAccuracy

NOT_APPLICABLE: dict[SystemKind, dict[str, str]] = {
    FOURIER: {
        "debye_points": "the pupil-plane field is closed-form (exact defocus phase), no quadrature",
        "propagator=fresnel_ir": "changes the grid; the per-lenslet path is the single-FFT Fresnel transform",
    },
    CONVENTIONAL: {
        "propagator": "always the Fresnel transfer function of the whole lenslet region (one FFT grid)",
        "padding": "fixed: the canvas plus at least half a pitch each side (conventional_patterns.fft_pitches)",
        "light_margin": "every lenslet within the reach is propagated (one FFT carries them all)",
        "per_lenslet": "lenslets are always summed coherently on one sensor grid",
    },
}
"""Knobs that do not reach a system kind's computation, with the reason."""

REFERENCE_MARGIN_AIRY = (64.0, 96.0)  # per-lenslet window margin: reference, refined
REFERENCE_FOURIER_SAMPLING = {"per_lenslet": (2, 3), "full_field": (6, 8)}  # s: reference, refined


@dataclass(frozen=True)
class KnobSetting:
    """One point of the sweep: engine options and the knob (and value) that sets them apart."""

    knob: str
    value: str
    options: EngineOptions

    @property
    def label(self) -> str:
        """``knob=value`` (the point's name in tables and plots)."""
        return f"{self.knob}={self.value}"


def preset_options(case: BenchCase, preset: str) -> EngineOptions:
    """Engine options of accuracy preset ``preset`` for ``case`` (through :mod:`from_design`)."""
    design = evolve(case.design, "accuracy", AccuracySpec.from_preset(preset))
    return fourier_accuracy_of(design) if case.system_kind is FOURIER else conventional_accuracy_of(design)


def uses_full_field(case: BenchCase, options: EngineOptions) -> bool:
    """Whether a Fourier case computes the full sensor field with these options."""
    from lfm_studio.engine.systems.fourier_psf import resolve_method
    from lfm_studio.engine.systems.from_design import fourier_system_of

    if not isinstance(options, FourierAccuracy):
        return False
    return resolve_method(fourier_system_of(case.design), case.depths, options)[0] == "full_field"


def footprints_overlap_in(case: BenchCase) -> bool:
    """Whether a Fourier case's lenslet footprints overlap (its reference is then the full field:
    the independent computation, not the coherent per-lenslet sum it checks)."""
    from lfm_studio.engine.systems.fourier_psf import footprints_overlap
    from lfm_studio.engine.systems.from_design import fourier_system_of

    return footprints_overlap(fourier_system_of(case.design), case.depths, FourierAccuracy())


def _extrapolated(
    low: EngineOptions, high: EngineOptions, a: int, b: int
) -> list[tuple[EngineOptions, float]]:
    """Richardson weights for two midpoint-rule samplings with ``a < b`` samples per pixel (error ~ 1/s^2)."""
    return [(low, -(a * a) / (b * b - a * a)), (high, (b * b) / (b * b - a * a))]


def reference_plan(case: BenchCase, *, refined: bool = False) -> list[tuple[EngineOptions, float]]:
    """The converged reference as weighted engine runs: ``sum(weight * stack(options))``.

    - Fourier: one float64 run with the exact (Fourier) pixel integration, which is exact once
      the intensity is sampled without aliasing (XLFM lenslets: s = 1, 2 and 3 agree to 1.5e-6
      and 2e-14). Per lenslet: s = 2 (refined: 3), window margin 64 (96) Airy lengths. Full field
      (sub-images overlap): s = 6 (refined: 8), band-limited ASM, padding 2; there the lenslet
      edges are sampled on the same grid, so the result still moves with s (Guo: 5e-4 from
      s = 3 to 6).
    - conventional: the midpoint pixel integral (``m x m`` sub-samples) converges as ``1/m^2``,
      so the reference is the Richardson extrapolation of m = 5 and 7 (refined: 7 and 9), NIP
      grid x1.5 (x2), the converged Debye quadrature.
    """
    if case.system_kind is FOURIER:
        full = footprints_overlap_in(case)
        s = REFERENCE_FOURIER_SAMPLING["full_field" if full else "per_lenslet"][int(refined)]
        options = FourierAccuracy(
            oversampling=s,
            margin_airy=REFERENCE_MARGIN_AIRY[int(refined)],
            model="debye",
            dtype=torch.float64,
            method="full_field" if full else "per_lenslet",
            depth_chunk=1,
            propagator="bandlimited_asm",
            padding=2.0,
            pixel_integration="fourier",
        )
        return [(options, 1.0)]
    from lfm_studio.engine.systems.conventional_patterns import sub_samples
    from lfm_studio.engine.systems.from_design import conventional_system_of

    system = conventional_system_of(case.design)
    a, b = (7, 9) if refined else (5, 7)
    nyquist_ratio = system.wavelength * system.mla_to_camera / (2.0 * system.pitch) / system.pixel_size
    base = ConventionalAccuracy(
        dtype=torch.float64,
        model="debye",
        debye_points=None,
        nip_oversampling=2.0 if refined else 1.5,
        radial_sampling=8,
        depth_chunk=64,
    )
    # pixel_oversampling giving exactly m sub-samples: just under m Nyquist-interval ratios.
    low, high = (dataclasses.replace(base, pixel_oversampling=(m - 0.5) * nyquist_ratio) for m in (a, b))
    assert (sub_samples(system, low.pixel_oversampling), sub_samples(system, high.pixel_oversampling)) == (
        a,
        b,
    )
    return _extrapolated(low, high, a, b)


def _text(value: object) -> str:
    if isinstance(value, torch.dtype):
        return str(value).removeprefix("torch.")
    return f"{value:g}" if isinstance(value, float) else str(value)


def _vary(base: EngineOptions, knob: str, values, field: str | None = None) -> list[KnobSetting]:
    """Settings with ``field`` (default ``knob``) set to each of ``values`` other than the base's."""
    field = field or knob
    return [
        KnobSetting(knob, _text(v), dataclasses.replace(base, **{field: v}))
        for v in values
        if getattr(base, field) != v
    ]


def fourier_settings(case: BenchCase, *, quick: bool = False) -> list[KnobSetting]:
    """One-knob-at-a-time Fourier settings around the standard preset."""
    base = preset_options(case, "standard")
    full = uses_full_field(case, base)
    settings = _vary(base, "oversampling", (1,) if quick else (1, 2, 3, 4))
    # The sub-sample sum (midpoint rule) at the standard sampling and at finer ones.
    midpoint = dataclasses.replace(base, pixel_integration="midpoint")
    for s in (base.oversampling,) if quick else (base.oversampling, 3, 6):
        value = "midpoint" if s == base.oversampling else f"midpoint, s={s}"
        settings.append(
            KnobSetting("pixel_integration", value, dataclasses.replace(midpoint, oversampling=s))
        )
    settings += _vary(base, "dtype", (torch.float64,))
    settings += _vary(base, "objective_model", ("paraxial",), field="model")
    overlap = footprints_overlap_in(case)
    if overlap:  # intensities added per lenslet where sub-images overlap (interference is lost)
        settings.append(KnobSetting("method", "per_lenslet", dataclasses.replace(base, method="per_lenslet")))
    if overlap and not full:  # the full field at the standard sampling (the coherent path's baseline)
        settings.append(KnobSetting("method", "full_field", dataclasses.replace(base, method="full_field")))
    # Propagator and padding act on the full-field path only; for a per-lenslet case they
    # are measured there at one sub-sample per pixel (labelled), to keep the cost sane
    # (the full XLFM field at s = 3 is a 16200^2 grid); "auto" there is the method=full_field row.
    if full or overlap:
        ff = dataclasses.replace(base, method="full_field")
        tag = "" if full else " (full field)"
    else:
        ff = dataclasses.replace(base, method="full_field", oversampling=1)
        tag = " (full field, s=1)"
    props = ("bandlimited_asm",) if quick else ("asm", "bandlimited_asm", "fresnel_tf", "auto")
    for prop in props:
        if full and prop == base.propagator:
            continue
        settings.append(KnobSetting("propagator", prop + tag, dataclasses.replace(ff, propagator=prop)))
    for pad in (1.0,) if quick else (1.0, 1.5, 3.0):
        settings.append(KnobSetting("padding", f"{pad:g}{tag}", dataclasses.replace(ff, padding=pad)))
    if not full:
        margins = (8.0,) if quick else (8.0, 16.0, 64.0)
        settings += [
            KnobSetting("margin_airy", f"{m:g}", dataclasses.replace(base, margin_airy=m)) for m in margins
        ]
        chunks = (1,) if quick else (1, 16)
        settings += _vary(base, "depth_chunk", chunks)
    return settings


def conventional_settings(case: BenchCase, *, quick: bool = False) -> list[KnobSetting]:
    """One-knob-at-a-time conventional settings around the standard preset."""
    base = preset_options(case, "standard")
    settings = _vary(base, "pixel_oversampling", (0.7,) if quick else (0.7, 1.4, 2.8, 4.2))
    # The midpoint rule at the standard sub-samples and at 5 (the standard preset before the
    # exact integral; sub_samples counts ceil(pixel * oversampling / nyquist), made odd).
    from lfm_studio.engine.systems.conventional_patterns import sub_samples
    from lfm_studio.engine.systems.from_design import conventional_system_of

    system = conventional_system_of(case.design)
    nyquist_ratio = system.wavelength * system.mla_to_camera / (2.0 * system.pitch) / system.pixel_size
    midpoint = dataclasses.replace(base, pixel_integration="midpoint")
    standard = sub_samples(system, base.pixel_oversampling)
    for m in (standard,) if quick else (standard, 5):
        options = dataclasses.replace(midpoint, pixel_oversampling=(m - 0.5) * nyquist_ratio)
        settings.append(KnobSetting("pixel_integration", f"midpoint, m={m}", options))
    settings += _vary(base, "nip_oversampling", (2.0,) if quick else (1.0, 1.5, 2.0))
    settings += _vary(base, "dtype", (torch.float64,))
    settings += _vary(base, "objective_model", ("paraxial",), field="model")
    settings += _vary(base, "debye_points", (64,) if quick else (48, 64, 96, 128))
    settings += _vary(base, "radial_sampling", ("exact",) if quick else (4, "exact"))
    settings += _vary(base, "depth_chunk", (1,))
    return settings


def sweep_settings(case: BenchCase, *, quick: bool = False) -> list[KnobSetting]:
    """The presets first (``preset=NAME``), then every knob setting of the case's system kind."""
    presets = [KnobSetting("preset", name, preset_options(case, name)) for name in ACCURACY_PRESETS]
    knobs = (
        fourier_settings(case, quick=quick)
        if case.system_kind is FOURIER
        else conventional_settings(case, quick=quick)
    )
    return presets + knobs
