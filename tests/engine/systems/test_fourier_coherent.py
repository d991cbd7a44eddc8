"""Per-lenslet Fourier PSF where lenslet footprints overlap: complex fields summed coherently.

Guo-like test design: 2 x 2 touching square lenslets (0.4 mm, pitch 0.4 mm) of 16 mm focal
length behind a 20x/0.5 water objective relayed by a 60 mm Fourier lens (pupil radius 1.5 mm
on the MLA), camera at the lenslets' focal plane, 8 um pixels. Their sub-images overlap in
the diffraction tails and, off focus, in the defocus blur: adding intensities loses the
interference; adding the complex fields keeps it.
"""

from __future__ import annotations

import dataclasses

import pytest
import torch

from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.optics.pixel_integration import integrate_pixels
from lfm_studio.engine.systems.fourier_lenslet import lenslet_field, lenslet_psf
from lfm_studio.engine.systems.fourier_parameters import FourierParameters
from lfm_studio.engine.systems.fourier_psf import (
    FourierAccuracy,
    FourierPSFReport,
    fourier_psf_stack,
    resolve_method,
)
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem
from lfm_studio.engine.systems.fourier_windows import plan_window
from lfm_studio.engine.units import mm, nm, um

OBJECTIVE = ObjectiveLens(20.0, 0.5, 1.33, 180 * mm)
F64 = torch.float64


def _system(centres, diameter=0.8 * mm, pitch=8 * um, sensor=(256, 256)) -> FourierLFMSystem:
    mla = MicrolensArray(tuple(Lenslet(c, diameter, 16 * mm, "square") for c in centres))
    return FourierLFMSystem(OBJECTIVE, 60 * mm, mla, 16 * mm, pitch, sensor, 525 * nm)


TOUCHING = _system(tuple((x * mm, y * mm) for x in (-0.2, 0.2) for y in (-0.2, 0.2)), diameter=0.4 * mm)
APART = _system(
    ((0.0, 0.0), (1.6 * mm, 0.3 * mm), (-0.9 * mm, -1.4 * mm)), diameter=0.5 * mm, sensor=(448, 448)
)
DEPTHS = (-30 * um, 0.0, 30 * um)


def _error(a: torch.Tensor, b: torch.Tensor) -> float:
    """Worst-depth relative L2 error of ``a`` against ``b``."""
    a, b = a.double(), b.double()
    return max(float((a[i] - b[i]).norm() / b[i].norm()) for i in range(b.shape[0]))


def test_coherent_sum_matches_the_full_field():
    # The standard preset's knobs (float32, Fourier pixels, 2 sub-samples).
    standard = FourierAccuracy(oversampling=2, method="per_lenslet_coherent")
    report = FourierPSFReport()
    coherent = fourier_psf_stack(TOUCHING, DEPTHS, accuracy=standard, report=report)
    assert coherent.metadata["method"] == "per_lenslet_coherent"
    assert coherent.metadata["coherent_lenslets"] == 4
    assert report.coherent_groups == [[0, 1, 2, 3]] and sorted(report.lenslets_computed) == [0, 1, 2, 3]
    full = fourier_psf_stack(
        TOUCHING,
        DEPTHS,
        accuracy=dataclasses.replace(standard, method="full_field", propagator="bandlimited_asm", dtype=F64),
    )
    incoherent = fourier_psf_stack(
        TOUCHING, DEPTHS, accuracy=dataclasses.replace(standard, method="per_lenslet")
    )
    error, lost = _error(coherent.data, full.data), _error(incoherent.data, full.data)
    # Within the standard preset's Fourier bound (1 %); adding intensities is several times worse.
    assert error < 0.01, error
    assert lost > 3 * error, (lost, error)


def test_auto_takes_the_cheaper_path_and_the_coherent_one_for_gradients():
    # 2 x 2 lenslets filling the crop: the full field on the windows' crop costs fewer samples
    # than four lenslets on the shared canvas; the crop is what it computes.
    standard = FourierAccuracy(oversampling=2)
    assert resolve_method(TOUCHING, DEPTHS, standard)[0] == "full_field"
    auto = fourier_psf_stack(TOUCHING, DEPTHS, accuracy=standard)
    assert auto.metadata["method"] == "full_field" and auto.metadata["full_field_pixels"][0] < 256
    whole = fourier_psf_stack(TOUCHING, DEPTHS, accuracy=dataclasses.replace(standard, method="full_field"))
    assert whole.metadata["full_field_pixels"] == [256, 256]
    assert _error(auto.data, whole.data) < 1e-3  # only the light beyond the windows is left out
    # Two touching lenslets in a wide array: the coherent pair is cheaper than the crop.
    pair = _system(
        ((-0.2 * mm, 0.0), (0.2 * mm, 0.0), (1.9 * mm, 1.9 * mm)), diameter=0.4 * mm, sensor=(640, 640)
    )
    assert resolve_method(pair, DEPTHS, standard)[0] == "per_lenslet_coherent"
    report = FourierPSFReport()
    parameters = FourierParameters(wavelength=torch.tensor(525 * nm, dtype=F64))
    fourier_psf_stack(TOUCHING, DEPTHS[:1], accuracy=standard, parameters=parameters, report=report)
    assert report.method == "per_lenslet_coherent" and report.coherent_groups == [[0, 1, 2, 3]]


def test_an_exact_propagator_keeps_the_full_field_where_footprints_overlap():
    exact = FourierAccuracy(oversampling=2, propagator="bandlimited_asm")
    assert resolve_method(TOUCHING, DEPTHS, exact)[0] == "full_field"
    assert resolve_method(APART, DEPTHS, exact)[0] == "per_lenslet"


def test_without_overlap_the_coherent_path_is_the_per_lenslet_path():
    assert resolve_method(APART, DEPTHS, FourierAccuracy(oversampling=2))[0] == "per_lenslet"
    old = fourier_psf_stack(APART, DEPTHS, accuracy=FourierAccuracy(oversampling=2, method="per_lenslet"))
    report = FourierPSFReport()
    new = fourier_psf_stack(
        APART, DEPTHS, accuracy=FourierAccuracy(oversampling=2, method="per_lenslet_coherent"), report=report
    )
    assert report.coherent_groups == [] and new.metadata["coherent_lenslets"] == 0
    assert _error(new.data, old.data) <= 1e-6


@pytest.mark.parametrize("lens_index", [0, 1])
def test_lenslet_field_modulus_is_the_lenslet_power(lens_index):
    # The field path (aperture box only, two 1D FFTs, phase ramps) against the power path.
    lens = APART.mla.lenslets[lens_index]
    z = torch.tensor(DEPTHS, dtype=F64)
    window = plan_window(APART, lens, DEPTHS, oversampling=2, margin_airy=32)
    power = lenslet_psf(APART, lens, window, z, oversampling=2, dtype=F64, pixel_integration="fourier")
    field = lenslet_field(APART, lens, window, z, oversampling=2, dtype=F64)
    from_field = integrate_pixels(field.real**2 + field.imag**2, 2, "fourier")
    assert _error(from_field, power) <= 1e-10


def test_coherent_path_is_differentiable():
    # Small touching pair, float64; gradient of a weighted PSF sum against central differences.
    system = _system(
        ((-0.1 * mm, 0.03 * mm), (0.1 * mm, 0.03 * mm)), diameter=0.2 * mm, pitch=16 * um, sensor=(64, 64)
    )
    acc = FourierAccuracy(oversampling=2, margin_airy=8, dtype=F64)
    depths = (-5 * um, 5 * um)
    weights = torch.rand(len(depths), 64, 64, generator=torch.Generator().manual_seed(0), dtype=F64)

    def loss(focal_mm: torch.Tensor, wavelength_um: torch.Tensor) -> torch.Tensor:
        parameters = FourierParameters(focal_lengths=focal_mm * mm, wavelength=wavelength_um * um)
        report = FourierPSFReport()
        stack = fourier_psf_stack(system, depths, accuracy=acc, parameters=parameters, report=report)
        assert report.coherent_groups == [[0, 1]]
        return (weights * stack.data).sum() * 1e3

    inputs = (
        torch.tensor([16.0, 16.0], dtype=F64, requires_grad=True),
        torch.tensor(0.525, dtype=F64, requires_grad=True),
    )
    assert torch.autograd.gradcheck(loss, inputs, eps=1e-6, atol=1e-6, rtol=1e-4)
