"""Fourier-LFM PSF stack: geometry, energy and diffraction checks, and the per-lenslet cache.

Test system: 20x/0.5 water objective (f_obj = 9 mm), Fourier lens 60 mm (pupil relayed
at m_r = 1/3, radius 1.5 mm on the MLA), lenslets 0.8 mm / 16 mm with the camera at
their focal plane, 4 um pixels: M_total = 20 * 16 / 60 = 5.33.
"""

from __future__ import annotations

import math
import threading

import pytest
import torch

from lfm_studio.engine.memory import MemoryBudgetError
from lfm_studio.engine.operators.fft_sizes import next_fast_length
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.optics.pupil_field import pupil_field
from lfm_studio.engine.optics.pupils import disk_coverage
from lfm_studio.engine.progress import CancelledError
from lfm_studio.engine.systems.fourier_psf import FourierAccuracy, FourierPSFReport, fourier_psf_stack
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem
from lfm_studio.engine.systems.fourier_windows import fast_samples, plan_window
from lfm_studio.engine.systems.lenslet_cache import LensletCache
from lfm_studio.engine.units import mm, nm, um

OBJECTIVE = ObjectiveLens(20.0, 0.5, 1.33, 180 * mm)
F_FOURIER, F_LENS, D_LENS, PITCH, WAVELENGTH = 60 * mm, 16 * mm, 0.8 * mm, 4 * um, 525 * nm
CENTRES = ((0.0, 0.0), (0.85 * mm, 0.0), (-0.45 * mm, 0.75 * mm))


def _system(centres=CENTRES, sensor=(560, 560), pitch=PITCH, focal=F_LENS, diameter=D_LENS):
    mla = MicrolensArray(tuple(Lenslet(c, diameter, focal) for c in centres))
    return FourierLFMSystem(OBJECTIVE, F_FOURIER, mla, F_LENS, pitch, sensor, WAVELENGTH)


def _centroid(image: torch.Tensor, centre_px: tuple[float, float], radius_px: int) -> tuple[float, float]:
    """Intensity centroid (row, col) in pixels within a square around ``centre_px``."""
    r0, c0 = (round(v) for v in centre_px)
    patch = image[r0 - radius_px : r0 + radius_px + 1, c0 - radius_px : c0 + radius_px + 1].double()
    rows = torch.arange(r0 - radius_px, r0 + radius_px + 1, dtype=torch.float64)
    cols = torch.arange(c0 - radius_px, c0 + radius_px + 1, dtype=torch.float64)
    total = patch.sum()
    return float((patch.sum(1) * rows).sum() / total), float((patch.sum(0) * cols).sum() / total)


def _pixel_of(system, x: float, y: float) -> tuple[float, float]:
    ny, nx = system.sensor_shape
    return y / system.pixel_pitch + ny // 2, x / system.pixel_pitch + nx // 2


def test_per_lenslet_equals_full_sensor_field_within_one_percent():
    # Reference: one MLA-plane grid over the whole sensor, band-limited ASM to the camera.
    # Per-lenslet differs by the Fresnel approximation (NA_lenslet = 0.025: phase error
    # ~ k d NA^4 / 8 = 0.0025 rad) and the light beyond each window (32 lambda d / D:
    # ~0.6 % of an Airy pattern's power, far less in L2 norm).
    system = _system()
    depths = (-40 * um, 0.0, 40 * um)
    fast = fourier_psf_stack(system, depths, accuracy=FourierAccuracy(method="per_lenslet", oversampling=2))
    full = fourier_psf_stack(
        system,
        depths,
        accuracy=FourierAccuracy(method="full_field", oversampling=2, propagator="bandlimited_asm"),
    )
    error = (fast.data - full.data).norm(dim=(1, 2)) / full.data.norm(dim=(1, 2))
    assert float(error.max()) < 0.01, error


def test_sub_images_centred_on_lenslets_and_shift_by_the_magnification():
    system = _system()
    acc = FourierAccuracy(oversampling=2, margin_airy=16)
    x0 = 3 * um
    centred = fourier_psf_stack(system, (0.0,), accuracy=acc).data[0]
    shifted = fourier_psf_stack(system, (0.0,), accuracy=acc, source_position=(x0, 0.0)).data[0]
    shift_px = system.magnification * x0 / system.pixel_pitch  # 4.0 px
    for cx, cy in CENTRES:
        expected = _pixel_of(system, cx, cy)
        row, col = _centroid(centred, expected, 12)
        # Symmetric in-focus spot: centroid exact up to float32 rounding.
        assert row == pytest.approx(expected[0], abs=0.02) and col == pytest.approx(expected[1], abs=0.02)
        row2, col2 = _centroid(shifted, (expected[0], expected[1] + shift_px), 12)
        assert col2 - col == pytest.approx(shift_px, rel=0.01)
        assert row2 == pytest.approx(row, abs=0.02)


def test_radial_shift_per_depth_follows_the_parallax_relation_of_eq_3_24():
    # Paraxial pupil: defocus phase -k z r^2 / (2 n f_obj^2 m_r^2) on the MLA, so the spot
    # behind a lenslet at radius r moves by -d z r / (n f_obj^2 m_r^2) = -d z r M^2 / (n f_F^2).
    # One Rayleigh radius 1.22 lambda d / D is reached at dz = 1.22 lambda n f_F^2 / (D r M^2):
    # eq. 3.24 with the immersion index.
    system = _system()
    acc = FourierAccuracy(oversampling=2, margin_airy=16, model="paraxial")
    z = 30 * um
    stack = fourier_psf_stack(system, (0.0, z), accuracy=acc).data
    m_obj = 20.0
    for cx, cy in CENTRES[1:]:
        r = math.hypot(cx, cy)
        expected = -F_LENS * z * r * m_obj**2 / (1.33 * F_FOURIER**2)  # metres, radial
        centre = _pixel_of(system, cx, cy)
        focus = _centroid(stack[0], centre, 20)
        moved = _centroid(
            stack[1], (centre[0] + expected * cy / r / PITCH, centre[1] + expected * cx / r / PITCH), 20
        )
        radial = ((moved[0] - focus[0]) * cy + (moved[1] - focus[1]) * cx) / r * PITCH
        assert radial == pytest.approx(expected, rel=0.01)
        dz_rayleigh = 1.22 * WAVELENGTH * 1.33 * F_FOURIER**2 / (D_LENS * r * m_obj**2)
        assert abs(expected / z) * dz_rayleigh == pytest.approx(
            1.22 * WAVELENGTH * F_LENS / D_LENS, rel=1e-12
        )


def test_energy_through_a_centred_lenslet_is_the_collected_solid_angle():
    # Aplanatic objective: uniform power per solid angle, so a centred lenslet of radius a
    # passes (1 - cos(theta)) / 2 of a unit emitter's power, sin(theta) = a / (m_r n f_obj).
    system = _system(centres=((0.0, 0.0),), sensor=(256, 256))
    lens = system.mla.lenslets[0]
    window = plan_window(system, lens, (0.0,), oversampling=2, margin_airy=32)
    stack = fourier_psf_stack(system, (0.0,), accuracy=FourierAccuracy(oversampling=2, dtype=torch.float64))
    # 1. Exact accounting: FFT, scaling, binning and placement keep the power of the sampled
    #    aperture field (Parseval), computed here independently on the same grid.
    n, dx, m_r = window.samples, window.input_spacing, system.relay_magnification
    relayed = pupil_field(
        OBJECTIVE, Grid(n, dx / m_r), WAVELENGTH, 0.0, check_sampling=False, dtype=torch.complex128
    )
    y, x = Grid(n, dx).axes()
    aperture = disk_coverage(x[None, :], y[:, None], D_LENS / 2, (dx, dx), antialias=True)
    sampled_power = float(((relayed.data.abs() / m_r) ** 2 * aperture**2).sum() * dx * dx)
    assert float(stack.data.sum()) == pytest.approx(sampled_power, rel=1e-10)
    # 2. Against the continuous aperture: the window holds the light diffracted up to its
    #    edge; beyond it are the Airy tail (2 / (pi v) = 0.6 % at 32 lambda d / D) and the
    #    antialiased edge samples (power c^2 instead of c: ~ (2 pi a / dx) (1/6) / (pi a^2 / dx^2)
    #    = 0.5 % at 34 samples per radius). Budget 1.5 %; measured 1.0 %.
    sin_t = (D_LENS / 2) / (m_r * 1.33 * 9 * mm)
    expected = (1 - math.sqrt(1 - sin_t**2)) / 2
    assert float(stack.data.sum()) == pytest.approx(expected, rel=0.015)
    assert float(stack.data.sum()) < expected


def test_in_focus_spot_is_the_lenslet_airy_pattern():
    # Uniform illumination of a circular lenslet (pupil amplitude varies by 0.3 % over it):
    # Airy FWHM 1.029 lambda d / D = 10.8 um. 0.5 um pixels resolve it to 2 %.
    system = _system(centres=((0.0, 0.0),), sensor=(128, 128), pitch=0.5 * um)
    stack = fourier_psf_stack(system, (0.0,), accuracy=FourierAccuracy(oversampling=1, margin_airy=8))
    row = stack.data[0, 64].double()
    peak = float(row.max())
    above = (row >= peak / 2).nonzero().flatten()
    left, right = int(above.min()), int(above.max())

    def crossing(i_in, i_out):  # linear interpolation of the half-maximum crossing
        a, b = float(row[i_in]), float(row[i_out])
        return i_in + (a - peak / 2) / (a - b) * (i_out - i_in)

    fwhm = (crossing(right, right + 1) - crossing(left, left - 1)) * 0.5 * um
    assert fwhm == pytest.approx(1.029 * WAVELENGTH * F_LENS / D_LENS, rel=0.02)


def test_editing_one_lenslet_recomputes_only_that_lenslet():
    cache = LensletCache()
    acc = FourierAccuracy(oversampling=1, margin_airy=8)
    first = FourierPSFReport()
    fourier_psf_stack(_system(), (0.0, 10 * um), accuracy=acc, cache=cache, report=first)
    assert first.lenslets_computed == [0, 1, 2]
    moved = (CENTRES[0], (0.9 * mm, 0.0), CENTRES[2])
    second = FourierPSFReport()
    fourier_psf_stack(_system(centres=moved), (0.0, 10 * um), accuracy=acc, cache=cache, report=second)
    assert second.lenslets_computed == [1] and second.lenslets_cached == [0, 2]
    assert cache.misses == 4 and cache.hits == 2


def test_cancel_stops_between_lenslets_and_progress_is_reported():
    calls = []
    stop = threading.Event()

    def progress(done, total, message):
        calls.append((done, total))
        if done == 1:
            stop.set()

    with pytest.raises(CancelledError):
        fourier_psf_stack(
            _system(),
            (0.0,),
            accuracy=FourierAccuracy(oversampling=1, margin_airy=8),
            progress=progress,
            cancel=stop,
        )
    assert calls == [(0, 3), (1, 3)]


def test_named_errors():
    with pytest.raises(ValueError, match="oversampling must be an integer >= 1; got 0"):
        FourierAccuracy(oversampling=0)
    with pytest.raises(ValueError, match="depths is empty"):
        fourier_psf_stack(_system(), ())


def test_a_window_too_large_for_memory_is_refused_before_it_is_planned():
    # Depths in um passed as metres: 10 m out of focus spreads a lenslet's light over ~1e8 samples
    # per side; planning it looped for ever in next_fast_length, computing it cannot fit anywhere.
    system, lens = _system(), _system().mla.lenslets[0]
    with pytest.raises(
        MemoryBudgetError, match=r"at depths up to 10 m \(\d+ x \d+ samples\).*Fix: give depths in metres"
    ):
        plan_window(system, lens, (-10.0, 0.0, 10.0), oversampling=2, margin_airy=32)
    with pytest.raises(
        ValueError, match=r"footprint of the lenslet at \(0, 0\) um is not finite.*Fix: give finite"
    ):
        plan_window(system, lens, (math.nan,), oversampling=2, margin_airy=32)


def test_fast_samples_is_the_smallest_even_fast_multiple_of_the_oversampling():
    for s in (1, 2, 3, 4, 6):
        for pixels in range(1, 400):
            samples = fast_samples(pixels, s)
            assert samples % s == 0 and samples % 2 == 0 and next_fast_length(samples) == samples
            smaller = range(pixels * s, samples, s)
            assert not any(m % 2 == 0 and next_fast_length(m) == m for m in smaller)
    with pytest.raises(
        ValueError, match=r"oversampling must have no prime factor above 5; got 7 .*Fix: use 2 or 3"
    ):
        fast_samples(10, 7)  # no multiple of 7 is a fast length: the old search never ended


def test_lone_lenslets_on_two_workers_give_the_one_thread_stack(monkeypatch):
    """The per-lenslet path runs its lenslets on run_in_workers threads (placed in lenslet order on
    the caller's thread); the stack must not depend on the worker count."""
    from lfm_studio.engine.systems import fourier_psf
    from lfm_studio.engine.threads import run_in_workers, torch_threads

    asked: list[int] = []

    def recording(task, items, workers, **options):
        asked.append(workers)
        return run_in_workers(task, items, workers, **options)

    monkeypatch.setattr(fourier_psf, "run_in_workers", recording)
    accuracy = FourierAccuracy(oversampling=1, margin_airy=8)
    with torch_threads(1):
        one = fourier_psf_stack(_system(), (-5 * um, 0.0, 5 * um), accuracy=accuracy).data
    report = FourierPSFReport()
    with torch_threads(2):
        two = fourier_psf_stack(_system(), (-5 * um, 0.0, 5 * um), accuracy=accuracy, report=report).data
    assert asked == [1, 2] and report.lenslets_computed == [0, 1, 2]
    assert float(one.max()) > 0.0
    torch.testing.assert_close(two, one, rtol=1e-6, atol=1e-7 * float(one.max()))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_lenslet_power_on_the_aperture_box_equals_the_whole_patch_transform(dtype):
    # lenslet_psf transforms only the box where the aperture is non-zero (zero-padded rows, then
    # columns); the reference evaluates the phasor on every patch sample and takes a centred fft2.
    from lfm_studio.engine.systems.fourier_lenslet import prepare_lenslet

    system = _system()
    lens = system.mla.lenslets[1]
    depths = torch.tensor([-40 * um, 0.0, 25 * um], dtype=torch.float64)
    window = plan_window(system, lens, tuple(depths.tolist()), oversampling=2, margin_airy=8.0)
    prepared = prepare_lenslet(system, lens, window, depths, 2, dtype=dtype)
    (r0, r1), (c0, c1) = prepared._support
    n = window.samples
    assert (r1 - r0) * (c1 - c0) < 0.5 * n * n  # the box really prunes the patch
    phase = (depths[:, None, None] * prepared.defocus + prepared.static_phase).double()
    odd = torch.arange(n).remainder(2).double()
    centred = torch.polar(prepared.amplitude.double().expand_as(phase), phase) * torch.exp(
        1j * math.pi * (odd[:, None] + odd[None, :])
    )
    reference = torch.fft.fft2(centred).abs() ** 2
    power = prepared.power(depths)
    assert power.dtype == dtype and power.shape == (3, n, n)
    tolerance = 2e-6 if dtype == torch.float32 else 1e-12
    assert float((power.double() - reference).abs().max() / reference.max()) < tolerance
