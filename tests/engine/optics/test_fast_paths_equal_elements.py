"""The fast PSF paths equal compositions of the public optical elements (float64, small grids).

Fourier LFM, one lenslet: ``pupil_field`` (relayed by ``m_r``) -> ``thin_lens`` (circle) or
``apply_mla`` (square) -> ``propagate(method="fresnel_ir")`` -> intensity -> ``s x s`` bins,
against :func:`lenslet_psf`. The lenslet centre is moved onto the window's sample
lattice (output shift 0: both sides then sample the same points; the sub-pixel shift
ramp is checked by the centre-gradient and sub-image position tests).

Conventional LFM: the native-image-plane Debye field of an offset source -> ``apply_mla``
(one lenslet at a time) -> zero padding onto the periodic plane of :func:`fft_pitches` pitches,
moved to the lenslet's axis -> ``fresnel_tf`` -> the lenslets' fields added -> the centred canvas
-> intensity -> bins, against :func:`offset_pattern` (NIP grid = sensor sub-sample grid); also
with a clear aperture smaller than the pitch (square and circle, antialiased in both).
"""

from __future__ import annotations

import dataclasses
import warnings

import pytest
import torch

from lfm_studio.engine.errors import SamplingWarning
from lfm_studio.engine.optics.debye import debye_psf
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.lenses import thin_lens
from lfm_studio.engine.optics.mla import apply_mla
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.optics.padding import pad_field
from lfm_studio.engine.optics.propagation import propagate
from lfm_studio.engine.optics.pupil_field import pupil_field
from lfm_studio.engine.systems.conventional_patterns import (
    fft_pitches,
    offset_pattern,
    samples_per_pitch,
    sub_samples,
)
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem
from lfm_studio.engine.systems.fourier_lenslet import lenslet_psf
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem
from lfm_studio.engine.systems.fourier_windows import plan_window
from lfm_studio.engine.units import mm, nm, um

F64, C128 = torch.float64, torch.complex128
TOLERANCE = 1e-6


def _relative_error(fast: torch.Tensor, reference: torch.Tensor) -> float:
    return float((fast - reference).abs().max() / reference.abs().max())


def _bin(power: torch.Tensor, s: int) -> torch.Tensor:
    z, ny, nx = power.shape
    return power.reshape(z, ny // s, s, nx // s, s).sum(dim=(2, 4))


# -- Fourier LFM ------------------------------------------------------------------------------
FOURIER_DEPTHS = (-6 * um, 0.0, 5 * um)


def _fourier_case(centre: tuple[float, float], shape: str):
    """A one-lenslet system with the lens moved onto its window's sample lattice (zero output shift)."""
    objective = ObjectiveLens(20.0, 0.5, 1.33, 180 * mm)

    def system_with(c):
        lens = Lenslet(c, 0.25 * mm, 4 * mm, shape)
        return FourierLFMSystem(
            objective, 60 * mm, MicrolensArray((lens,)), 5 * mm, 8 * um, (128, 128), 525 * nm
        ), lens

    system, lens = system_with(centre)
    window = plan_window(system, lens, FOURIER_DEPTHS, oversampling=2, margin_airy=4)
    system, lens = system_with((centre[0] + window.shift[1], centre[1] + window.shift[0]))
    window = plan_window(system, lens, FOURIER_DEPTHS, oversampling=2, margin_airy=4)
    assert max(abs(v) for v in window.shift) < 1e-15  # metres
    return system, lens, window


@pytest.mark.parametrize(
    ("centre", "shape"),
    [((0.0, 0.0), "circle"), ((0.21 * mm, -0.13 * mm), "circle"), ((0.0, 0.0), "square"), ((-0.17 * mm, 0.24 * mm), "square")],
)  # fmt: skip
def test_fourier_lenslet_equals_pupil_lens_fresnel_composition(centre, shape):
    system, lens, window = _fourier_case(centre, shape)
    z = torch.tensor(FOURIER_DEPTHS, dtype=F64)
    fast = lenslet_psf(system, lens, window, z, oversampling=2, dtype=F64, antialias=True)

    n, dx, m_r, s = window.samples, window.input_spacing, system.relay_magnification, 2
    cx, cy = lens.center
    pupil = pupil_field(
        system.objective, Grid(n, dx / m_r), system.wavelength, z, center=(cx / m_r, cy / m_r),
        check_sampling=False, dtype=C128,
    )  # fmt: skip
    relayed = Field(pupil.data / m_r, Grid(n, dx), system.wavelength)  # 4f relay: scale m_r, amplitude 1/m_r
    with warnings.catch_warnings():
        # The lens phase alone is undersampled on this patch; with the Fresnel input chirp
        # of an in-focus camera the product is smooth (the fast path forms that product).
        warnings.simplefilter("ignore", SamplingWarning)
        if shape == "circle":
            lensed = thin_lens(
                relayed, lens.focal_length, aperture_diameter=lens.aperture_diameter, antialias=True
            )
        else:
            array = MicrolensArray((dataclasses.replace(lens, center=(0.0, 0.0)),))
            lensed = apply_mla(relayed, array, antialias=True)
        sensor = propagate(
            lensed, system.mla_to_camera, method="fresnel_ir", padding=1.0, check_sampling=False
        )
    assert sensor.grid.dx == pytest.approx(system.pixel_pitch / s, rel=1e-12)
    reference = _bin(sensor.intensity() * sensor.grid.pixel_area, s)
    assert fast.shape == reference.shape == (len(FOURIER_DEPTHS), n // s, n // s)
    assert _relative_error(fast, reference) <= TOLERANCE


# -- Conventional LFM -------------------------------------------------------------------------
def _conventional_case() -> ConventionalLFMSystem:
    """A small system (50 um pitch, camera in the lenslets' focal plane) whose NIP samples per pitch
    equal the sensor sub-samples per pitch (15 = 5 px x 3), so no resampling enters."""
    pitch, wavelength, q = 50 * um, 525 * nm, 5
    system = ConventionalLFMSystem(
        ObjectiveLens(10.0, 0.3, 1.0, 200 * mm), pitch, 1 * mm, "square", 1 * mm, (3, 3), q, 3, wavelength
    )
    assert samples_per_pitch(system) == q * sub_samples(system) == 15
    return system


@pytest.mark.parametrize(
    ("a", "b", "shape", "fill"),
    [(0, 0, "square", None), (0, 1, "square", None), (1, 1, "square", None), (1, 1, "square", 0.77),
     (0, 1, "circle", 0.83)],
)  # fmt: skip
def test_conventional_pattern_equals_nip_mla_fresnel_composition(a, b, shape, fill):
    system = _conventional_case()
    aperture = None if fill is None else fill * system.pitch
    system = dataclasses.replace(system, lenslet_shape=shape, lenslet_aperture=aperture)
    reach, depths = 1, (0.0, 8 * um)
    ns, m, s = samples_per_pitch(system), sub_samples(system), system.voxels_per_lenslet
    dx, step, mag = system.pitch / ns, ns // s, system.magnification
    z = torch.tensor(depths, dtype=F64)
    field_n = (2 * reach + 1) * ns + 2 * (s // 2) * step
    base = debye_psf(system.objective, Grid(field_n, dx), system.wavelength, z, image_side=True,
                     radial_sampling="exact", dtype=C128).data  # fmt: skip
    fast = offset_pattern(system, base, a, b, reach=reach, dtype=F64)

    # Every lenslet alone: its NIP patch through apply_mla, placed at its axis on the periodic plane
    # of fft_pitches(reach) pitches, propagated by the Fresnel transfer function, fields summed.
    plane_n = fft_pitches(reach) * ns
    total = torch.zeros((len(depths), plane_n, plane_n), dtype=C128)
    lens = MicrolensArray((Lenslet((0.0, 0.0), system.aperture, system.lenslet_focal_length, shape),))
    for i in range(-reach, reach + 1):
        for j in range(-reach, reach + 1):
            # The NIP field on lenslet (i, j)'s own ns x ns patch, centred on its axis: the source's
            # image sits at (b step dx - j P, a step dx - i P) from it (object side: / -M).
            image_x, image_y = b * step * dx - j * system.pitch, a * step * dx - i * system.pitch
            nip = debye_psf(
                system.objective, Grid(ns, dx), system.wavelength, z, position=(-image_x / mag, -image_y / mag),
                image_side=True, radial_sampling="exact", dtype=C128,
            )  # fmt: skip
            lensed = pad_field(apply_mla(nip, lens, antialias=fill is not None), shape=(plane_n, plane_n))
            placed = lensed.with_data(torch.roll(lensed.data, (i * ns, j * ns), dims=(-2, -1)))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", SamplingWarning)
                sensor = propagate(
                    placed, system.mla_to_camera, method="fresnel_tf", padding=1.0, check_sampling=False
                )
            total += sensor.data
    canvas_n = (2 * reach + 3) * ns  # centred on the source lenslet's axis (the plane's centre)
    first = plane_n // 2 - canvas_n // 2
    canvas = total[:, first : first + canvas_n, first : first + canvas_n]
    reference = _bin((canvas.real**2 + canvas.imag**2) * dx * dx, m)
    assert fast.shape == reference.shape
    assert _relative_error(fast, reference) <= TOLERANCE
