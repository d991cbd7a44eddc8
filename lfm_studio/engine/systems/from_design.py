"""Build engine systems and accuracy settings from a validated :class:`Design`.

The one place where the user-facing spec (units in key names) meets the engine's SI
objects; each spec already converts its own units (``spec.focal_length`` in metres).
"""

from __future__ import annotations

import torch

from lfm_studio.engine.design import Design
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.systems.fourier_psf import FourierAccuracy
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem

_DTYPES = {"float32": torch.float32, "float64": torch.float64}


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


def fourier_system_of(design: Design) -> FourierLFMSystem:
    """The Fourier LFM described by ``design`` (``kind == "fourier"``)."""
    if design.kind != "fourier":
        raise ValueError(f"design kind must be 'fourier' for a Fourier LFM; got {design.kind!r}.")
    return FourierLFMSystem(
        objective=objective_of(design),
        fourier_focal_length=design.relay.focal_length,
        mla=microlens_array_of(design),
        mla_to_camera=design.mla_to_camera_distance,
        pixel_pitch=design.camera.pixel_pitch,
        sensor_shape=tuple(design.camera.pixel_count),
        wavelength=design.wavelength,
    )


def fourier_accuracy_of(design: Design) -> FourierAccuracy:
    """The Fourier-LFM accuracy knobs of ``design.accuracy``."""
    spec = design.accuracy
    return FourierAccuracy(
        oversampling=max(1, int(spec.oversampling)),
        model=spec.objective_model,
        dtype=_DTYPES[spec.dtype],
        method="auto" if spec.per_lenslet else "full_field",
        depth_chunk=spec.depth_chunk,
        propagator=spec.propagator,
    )
