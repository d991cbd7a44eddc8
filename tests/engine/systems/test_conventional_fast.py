"""Conventional LFM lattice transform (FFT Fresnel transfer function, separable row and column passes,
row passes shared by the sources of one column offset) against a plain per-lenslet evaluation.

The reference carries every lenslet alone: its NIP patch times the lens phase (and aperture) on a
zero plane of ``fft_pitches(reach)`` pitches, a 2-D FFT, the 2-D Fresnel transfer function, and the
band-limited field evaluated at the sensor sub-sample centres by an explicit sum of its Fourier
series (no FFT resampling); the lenslets' fields are added, then ``|U|^2`` and the pixels.

Small test system as in ``test_conventional.py`` (10x/0.3, 125 um lenslets, 5 px and 3 voxels
per lenslet): 51 NIP samples per pitch against 45 sensor sub-samples, so the resampling is
exercised. float64 throughout, so the two code paths agree to round-off.
"""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.optics.phase_kernels import aperture_coverage
from lfm_studio.engine.optics.pixel_integration import integrate_pixels
from lfm_studio.engine.systems.conventional_patterns import (
    conventional_patterns,
    fft_pitches,
    nip_fields,
    nip_quadrants,
    offset_pattern,
    samples_per_pitch,
    sub_samples,
)
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem
from lfm_studio.engine.units import mm, nm, um

F64 = torch.float64


def _system(shape: str, aperture: float | None = None) -> ConventionalLFMSystem:
    return ConventionalLFMSystem(
        ObjectiveLens(10, 0.3, 1.0, 200 * mm), 125 * um, 1.875 * mm, shape, 1.875 * mm, (5, 5), 5, 3, 525 * nm,
        aperture,
    )  # fmt: skip


def _per_lenslet_pattern(
    system: ConventionalLFMSystem,
    field: torch.Tensor,
    a: int,
    b: int,
    reach: int,
    integration: str = "midpoint",
) -> torch.Tensor:
    """Reference: each lenslet's patch alone through a 2-D FFT transfer-function propagation, fields summed;
    the pixels by ``integration`` (the 2-D :func:`integrate_pixels` of the sensor-field power)."""
    ns, m, q = samples_per_pitch(system), sub_samples(system), system.pixels_per_lenslet
    step, p = ns // system.voxels_per_lenslet, system.pitch
    dx = p / ns
    n = fft_pitches(reach) * ns
    k = 2 * math.pi / system.wavelength
    y, x = Grid(ns, dx).axes()
    weight = torch.exp(-1j * k * (x[None, :] ** 2 + y[:, None] ** 2) / (2 * system.lenslet_focal_length))
    if system.lenslet_aperture is not None or system.lenslet_shape == "circle":
        clear = system.aperture
        coverage = aperture_coverage(
            system.lenslet_shape, x[None, :], y[:, None], clear, (dx, dx), antialias=True
        )
        weight = weight * coverage
    freq = torch.fft.fftfreq(n, dx, dtype=F64)
    transfer = torch.exp(
        -1j * math.pi * system.wavelength * system.mla_to_camera * (freq[:, None] ** 2 + freq**2)
    )
    spectrum = torch.zeros((n, n), dtype=torch.complex128)
    centre = field.shape[-1] // 2
    for i in range(-reach, reach + 1):
        for j in range(-reach, reach + 1):
            cy, cx = centre - a * step + i * ns, centre - b * step + j * ns
            patch = field[cy - ns // 2 : cy + ns // 2 + 1, cx - ns // 2 : cx + ns // 2 + 1] * weight
            plane = torch.zeros((n, n), dtype=torch.complex128)  # index n // 2 is the source lenslet's axis
            top, left = n // 2 + i * ns - ns // 2, n // 2 + j * ns - ns // 2
            plane[top : top + ns, left : left + ns] = patch
            spectrum += torch.fft.fft2(plane) * transfer
    # The sensor field at the sub-sample centres (c - C // 2) P / (Q m): its Fourier series, explicitly.
    out_n = q * m
    canvas = (2 * reach + 3) * out_n
    half = (min(n, fft_pitches(reach) * out_n) - 1) // 2
    freqs = torch.arange(-half, half + 1)
    u = (torch.arange(canvas, dtype=F64) - canvas // 2) * (p / out_n) / dx + n // 2  # in input samples
    series = torch.exp(2j * math.pi * u[:, None] * freqs[None, :] / n) / n
    kept = spectrum[freqs % n][:, freqs % n]
    sensor = series @ kept @ series.T
    power = sensor.abs() ** 2 * (p / out_n) ** 2
    h = power.shape[-1] // m
    if integration == "fourier":
        return integrate_pixels(power, m, "fourier")
    return power.reshape(h, m, h, m).sum(dim=(1, 3))


@pytest.mark.parametrize(("shape", "aperture"), [("square", None), ("square", 100 * um), ("circle", None)])
def test_lattice_transform_equals_the_per_lenslet_sum(shape, aperture):
    system = _system(shape, aperture)
    assert samples_per_pitch(system) != system.pixels_per_lenslet * sub_samples(system)  # resampled
    z = -80 * um
    reach = system.support(z)
    base = nip_fields(system, (z,), reach=reach, dtype=F64)
    patterns = conventional_patterns(system, (z,), reach=reach, dtype=F64, nip_field=base)[0]
    half = system.voxels_per_lenslet // 2
    for a, b in [(0, 0), (0, 1), (1, 1), (1, -1)]:  # (1, -1): a mirrored copy of (1, 1)
        reference = _per_lenslet_pattern(system, base[0], a, b, reach)
        fast = offset_pattern(system, base, a, b, reach=reach, dtype=F64)[0]
        assert torch.allclose(fast, reference, rtol=0, atol=1e-10 * float(reference.max())), (a, b)
        mirrored = patterns[a + half, b + half]
        assert torch.allclose(mirrored, reference, rtol=0, atol=1e-10 * float(reference.max())), (a, b)


@pytest.mark.parametrize("shape", ["square", "circle"])
def test_fourier_pixel_integration_equals_the_per_lenslet_sum_filtered(shape):
    # The exact box integral of the same sensor-field power (integrate_pixels "fourier" on the canvas).
    system = _system(shape)
    z = -80 * um
    reach = system.support(z)
    base = nip_fields(system, (z,), reach=reach, dtype=F64)
    for a, b in [(0, 0), (1, -1)]:
        reference = _per_lenslet_pattern(system, base[0], a, b, reach, "fourier")
        fast = offset_pattern(system, base, a, b, reach=reach, dtype=F64, pixel_integration="fourier")[0]
        assert torch.allclose(fast, reference, rtol=0, atol=1e-10 * float(reference.max())), (a, b)


def test_fourier_pixel_integration_converges_where_the_midpoint_rule_does_not():
    # The exact box integral of the sampled intensity is exact once the intensity is sampled without
    # aliasing (field band P / (2 lambda f) + NA_img / lambda, so ~60 samples per pitch here: 5 px x
    # 13); at 45 per pitch (9 per pixel, the engine's default) it is 5x closer than the midpoint rule.
    system = _system("square")
    nyquist = system.wavelength * system.mla_to_camera / (2.0 * system.pitch) / system.pixel_size
    z = -80 * um
    reach = system.support(z)
    base = nip_fields(system, (z,), reach=reach, dtype=F64)

    def pattern(m: int, integration: str) -> torch.Tensor:
        oversampling = (m - 0.5) * nyquist
        assert sub_samples(system, oversampling) == m
        return offset_pattern(
            system,
            base,
            1,
            0,
            reach=reach,
            dtype=F64,
            oversampling=oversampling,
            pixel_integration=integration,
        )[0]

    converged = pattern(15, "fourier")
    # The midpoint rule's Richardson extrapolation (error ~ 1/m^2) lands on it too (measured 9e-5).
    richardson = (225 * pattern(15, "midpoint") - 169 * pattern(13, "midpoint")) / 56
    assert float((richardson - converged).norm() / converged.norm()) < 3e-4

    def error(m: int, integration: str) -> float:
        return float((pattern(m, integration) - converged).norm() / converged.norm())

    assert error(13, "fourier") < 5e-5  # measured 8e-6 (against 2.5e-3 for the midpoint rule)
    fourier, midpoint = error(9, "fourier"), error(9, "midpoint")  # measured 1.1e-3, 5.7e-3
    assert fourier < 2e-3 and 4 * fourier < midpoint, (fourier, midpoint)
    with pytest.raises(ValueError, match="pixel_integration must be one of"):
        offset_pattern(system, base, 0, 0, reach=reach, dtype=F64, pixel_integration="simpson")


def test_patterns_written_in_place_equal_the_returned_stack():
    system = _system("square")
    depths = (-60 * um, 20 * um)
    reach = max(system.support(z) for z in depths)
    base = nip_fields(system, depths, reach=reach, dtype=F64)
    returned = conventional_patterns(system, depths, reach=reach, dtype=F64, nip_field=base)
    s, h = system.voxels_per_lenslet, returned.shape[-1]
    out = torch.full((s, s, 4, h + 2, h + 2), -1.0, dtype=F64)
    view = out[:, :, 1:3, 1 : h + 1, 1 : h + 1]
    assert conventional_patterns(system, depths, reach=reach, dtype=F64, nip_field=base, out=view) is view
    assert torch.equal(view.permute(2, 0, 1, 3, 4), returned)
    assert bool((out[:, :, 0] == -1).all()) and bool((out[..., 0] == -1).all())  # nothing else touched
    with pytest.raises(ValueError, match="out has shape"):
        conventional_patterns(system, depths, reach=reach, dtype=F64, nip_field=base, out=out)


def test_fft_grid_holds_the_canvas_and_padding_at_fast_lengths():
    for reach in range(12):
        pitches = fft_pitches(reach)
        assert pitches >= 2 * reach + 4
        rest = pitches
        for prime in (2, 3, 5):
            while rest % prime == 0:
                rest //= prime
        assert rest == 1, pitches
    assert [fft_pitches(r) for r in (1, 2, 5, 6)] == [6, 8, 15, 16]


@pytest.mark.parametrize("waves", [None, {11: 0.2}])
def test_the_field_at_minus_z_taken_from_plus_z_equals_its_own_integration(waves):
    # Without a pupil phase U(-z) = -conj(U(z)) and only one of a pair is integrated; a phase mask
    # breaks the symmetry and both are integrated.
    system = _system("square")
    pair = nip_quadrants(system, (-40 * um, 40 * um, 0.0), reach=1, dtype=F64, zernike_waves=waves)
    for index, z in enumerate((-40 * um, 40 * um, 0.0)):
        alone = nip_quadrants(system, (z,), reach=1, dtype=F64, zernike_waves=waves)[0]
        assert torch.allclose(pair[index], alone, rtol=0, atol=1e-12 * float(alone.abs().max())), z
