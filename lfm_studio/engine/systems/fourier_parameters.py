"""Tensor overrides of a Fourier LFM's optics, for gradients through the per-lenslet PSF.

The system dataclasses hold plain floats (they are hashed, validated and planned
with), so differentiable values travel next to them in a :class:`FourierParameters`
passed to :func:`~lfm_studio.engine.systems.fourier_psf.fourier_psf_stack`. The split:

- **geometry** (the per-lenslet window: sample count, sensor placement, footprint) is
  planned from the *values* of the parameters (:meth:`FourierParameters.applied_to`
  writes them into a plain-float system first), so it is discrete and carries no gradient;
- **physics** (lens phase, Fresnel chirp, shift ramp, aperture coverage, pupil field,
  input spacing ``lambda d s / (N p)``, normalisation) is evaluated from the tensors, so
  gradients reach every overridden value.

A lenslet centre moves the sub-image by a Fourier-domain phase ramp (a sub-pixel shift
of the output samples, :func:`~lfm_studio.engine.optics.phase_kernels.shift_ramp`) and
moves the part of the pupil it samples; the NA enters through an antialiased pupil rim
(:func:`~lfm_studio.engine.optics.pupil_field.pupil_terms_at`), which is used whenever
``numerical_aperture`` is given (a binary rim has no gradient). A ``pupil_phase``
(:class:`~lfm_studio.engine.optics.phase_mask.PhaseMask` on the MLA plane, the
BFP-conjugate plane where an SLM sits in the relay) is sampled bilinearly on each
lenslet's patch. ``zernike_waves`` (``{noll index: 0-d tensor in waves}``) overrides or adds
terms of the system's Zernike pupil phase (``FourierLFMSystem.pupil_zernike_waves``, a
design's ``pupil_phase``), evaluated in closed form where the pupil field is
(:func:`~lfm_studio.engine.optics.pupil_field.pupil_terms_at`). The lenslet cache is
bypassed whenever parameters are given.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import torch

from lfm_studio.engine.optics.mla_layout import Lenslet
from lfm_studio.engine.optics.objective import ObjectiveLens, _value
from lfm_studio.engine.optics.phase_mask import PhaseMask
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem

Scalar = float | torch.Tensor
_SCALARS = ("wavelength", "numerical_aperture", "mla_to_camera", "fourier_focal_length")


@dataclass(frozen=True)
class FourierParameters:
    """Differentiable values that override a :class:`FourierLFMSystem`'s floats (SI units).

    Attributes (each optional; ``None`` keeps the system's value)
    -------------------------------------------------------------
    focal_lengths : ``(L,)`` lenslet focal lengths, m.
    aperture_diameters : ``(L,)`` lenslet aperture diameters (circle) or sides (square), m.
    centers : ``(L, 2)`` lenslet centres ``(x, y)`` on the MLA plane, m.
    wavelength : 0-d, vacuum emission wavelength, m.
    numerical_aperture : 0-d, objective NA (antialiased pupil rim).
    mla_to_camera : 0-d, MLA-to-sensor distance, m.
    fourier_focal_length : 0-d, Fourier (relay) lens focal length, m.
    pupil_phase : phase mask on the MLA plane (grid centred on the optical axis), rad.
    zernike_waves : ``{noll index: 0-d tensor}``, Zernike pupil-phase coefficients in waves that
        override (or add to) the system's ``pupil_zernike_waves``.
    """

    focal_lengths: torch.Tensor | None = None
    aperture_diameters: torch.Tensor | None = None
    centers: torch.Tensor | None = None
    wavelength: torch.Tensor | None = None
    numerical_aperture: torch.Tensor | None = None
    mla_to_camera: torch.Tensor | None = None
    fourier_focal_length: torch.Tensor | None = None
    pupil_phase: PhaseMask | None = None
    zernike_waves: Mapping[int, torch.Tensor] | None = None

    def check(self, system: FourierLFMSystem) -> None:
        """Raise ``ValueError`` naming the field whose shape does not fit ``system``."""
        count = len(system.mla.lenslets)
        shapes = {
            "focal_lengths": (count,),
            "aperture_diameters": (count,),
            "centers": (count, 2),
            **{name: () for name in _SCALARS},
        }
        for name, shape in shapes.items():
            value = getattr(self, name)
            if value is None:
                continue
            if not isinstance(value, torch.Tensor) or tuple(value.shape) != shape or value.is_complex():
                raise ValueError(
                    f"FourierParameters.{name} must be a real tensor of shape {shape}; got "
                    f"{getattr(value, 'shape', type(value).__name__)}. Fix: e.g. torch.tensor(...) with "
                    f"{'one value per lenslet' if shape else 'a 0-d value'}."
                )
            if not bool(torch.isfinite(value.detach()).all()):
                raise ValueError(f"FourierParameters.{name} must be finite; got {value.detach()}.")
        for j, c in (self.zernike_waves or {}).items():
            if isinstance(j, bool) or not isinstance(j, int) or j < 1:
                raise ValueError(
                    f"FourierParameters.zernike_waves keys must be Noll indices >= 1; got {j!r}."
                )
            if not isinstance(c, torch.Tensor) or c.ndim != 0 or c.is_complex():
                raise ValueError(
                    f"FourierParameters.zernike_waves[{j}] must be a real 0-d tensor (waves); got "
                    f"{getattr(c, 'shape', type(c).__name__)}. Fix: e.g. torch.tensor(0.1, requires_grad=True)."
                )
            if not bool(torch.isfinite(c.detach())):
                raise ValueError(f"FourierParameters.zernike_waves[{j}] must be finite; got {c.detach()}.")
        if self.pupil_phase is not None and not isinstance(self.pupil_phase, PhaseMask):
            raise ValueError(
                f"FourierParameters.pupil_phase must be a PhaseMask; got {type(self.pupil_phase).__name__}."
            )

    def applied_to(self, system: FourierLFMSystem) -> FourierLFMSystem:
        """``system`` with the parameter *values* (detached floats) written in: what geometry is planned on."""
        self.check(system)
        lenses = []
        for i, lens in enumerate(system.mla.lenslets):
            lenses.append(
                Lenslet(
                    _pick(self.centers, i, lens.center),
                    _pick(self.aperture_diameters, i, lens.aperture_diameter),
                    _pick(self.focal_lengths, i, lens.focal_length),  # a tensor in the lens stays
                    lens.shape,
                )
            )
        objective = system.objective
        if self.numerical_aperture is not None:
            objective = dataclasses.replace(objective, numerical_aperture=_value(self.numerical_aperture))
        changes: dict[str, Any] = {
            name: _value(getattr(self, name))
            for name in ("wavelength", "mla_to_camera", "fourier_focal_length")
            if getattr(self, name) is not None
        }
        changes["objective"] = objective
        changes["mla"] = dataclasses.replace(system.mla, lenslets=tuple(lenses))
        if self.zernike_waves:
            terms = dict(system.pupil_zernike_waves)
            terms.update({j: _value(c) for j, c in self.zernike_waves.items()})
            changes["pupil_zernike_waves"] = tuple(terms.items())
        return dataclasses.replace(system, **changes)

    def zernike_terms(self, system: FourierLFMSystem) -> tuple[tuple[int, Scalar], ...]:
        """The system's Zernike pupil-phase terms with these overrides (tensors where given), by index."""
        terms: dict[int, Scalar] = dict(system.pupil_zernike_waves)
        terms.update({j: c.to(torch.float64) for j, c in (self.zernike_waves or {}).items()})
        return tuple(sorted(terms.items(), key=lambda item: item[0]))

    def lenslet(self, system: FourierLFMSystem, index: int) -> LensletOptics:
        """The optics lenslet ``index`` is computed with (tensors where overridden)."""
        lens = system.mla.lenslets[index]
        objective = system.objective
        if self.numerical_aperture is not None:
            objective = dataclasses.replace(objective, numerical_aperture=self.numerical_aperture)
        fourier = _or(self.fourier_focal_length, system.fourier_focal_length)
        center = lens.center if self.centers is None else (self.centers[index, 0], self.centers[index, 1])
        return LensletOptics(
            lens=lens,
            center=center,
            aperture_diameter=_pick_t(self.aperture_diameters, index, lens.aperture_diameter),
            focal_length=_pick_t(self.focal_lengths, index, lens.focal_length),
            wavelength=_or(self.wavelength, system.wavelength),
            mla_to_camera=_or(self.mla_to_camera, system.mla_to_camera),
            relay_magnification=fourier / objective.tube_lens_focal_length,
            objective=objective,
            pupil_phase=self.pupil_phase,
            soft_pupil_edge=self.numerical_aperture is not None,
            zernike_waves=self.zernike_terms(system),
        )


@dataclass(frozen=True)
class LensletOptics:
    """Everything one lenslet's PSF is computed from: floats or 0-d tensors (SI units).

    ``lens`` is the planned (float) lenslet; ``center`` etc. are the values the physics
    uses (equal to the planned ones, possibly tensors carrying gradients).
    """

    lens: Lenslet
    center: tuple[Scalar, Scalar]
    aperture_diameter: Scalar
    focal_length: Scalar
    wavelength: Scalar
    mla_to_camera: Scalar
    relay_magnification: Scalar
    objective: ObjectiveLens
    pupil_phase: PhaseMask | None = None
    soft_pupil_edge: bool = False
    zernike_waves: tuple[tuple[int, Scalar], ...] = ()

    @staticmethod
    def of(system: FourierLFMSystem, lens: Lenslet) -> LensletOptics:
        """The plain optics of ``lens`` in ``system`` (no overrides)."""
        return LensletOptics(
            lens=lens,
            center=lens.center,
            aperture_diameter=lens.aperture_diameter,
            focal_length=lens.focal_length,
            wavelength=system.wavelength,
            mla_to_camera=system.mla_to_camera,
            relay_magnification=system.fourier_focal_length / system.objective.tube_lens_focal_length,
            objective=system.objective,
            zernike_waves=system.pupil_zernike_waves,
        )


def _or(value: torch.Tensor | None, default: Scalar) -> Scalar:
    return default if value is None else value.to(torch.float64)


def _pick(values: torch.Tensor | None, index: int, default):
    if values is None:
        return default
    row = values.detach()[index]
    return tuple(float(v) for v in row) if row.ndim else float(row)


def _pick_t(values: torch.Tensor | None, index: int, default: Scalar) -> Scalar:
    return default if values is None else values[index].to(torch.float64)


def parameters_require_grad(parameters: FourierParameters | None, system: FourierLFMSystem) -> bool:
    """Whether any input of the PSF carries a gradient (then nothing may be cached)."""
    tensors: list[object] = []
    if parameters is not None:
        names = ("focal_lengths", "aperture_diameters", "centers", *_SCALARS)
        tensors += [getattr(parameters, name) for name in names]
        if parameters.pupil_phase is not None:
            tensors.append(parameters.pupil_phase.phase)
        tensors += list((parameters.zernike_waves or {}).values())
    tensors += [lens.focal_length for lens in system.mla.lenslets]
    tensors += [getattr(system.objective, f.name) for f in dataclasses.fields(system.objective)]
    return any(isinstance(t, torch.Tensor) and t.requires_grad for t in tensors)
