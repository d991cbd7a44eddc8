"""Conventional LFM: patterns against a full-field simulation, energy, symmetry, projector adjointness.

Small test system: 10x/0.3 air objective (200 mm tube lens), 125 um square lenslets of
1.875 mm focal length with the camera in their focal plane, 5 rectified pixels and 3
voxels per lenslet, 525 nm.
"""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.design import evolve, load_preset
from lfm_studio.engine.optics.camera import integrate_pixels
from lfm_studio.engine.optics.debye import debye_psf
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.mla import mla_transmission
from lfm_studio.engine.optics.mla_generators import square_grid
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.optics.propagation import propagate
from lfm_studio.engine.systems.conventional_patterns import (
    conventional_patterns,
    nip_field_size,
    nip_fields,
    offset_pattern,
    radial_table_sampling,
    samples_per_pitch,
)
from lfm_studio.engine.systems.conventional_psf import conventional_projector
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem
from lfm_studio.engine.systems.from_design import conventional_system_of
from lfm_studio.engine.units import mm, nm, um

SYSTEM = ConventionalLFMSystem(
    ObjectiveLens(10, 0.3, 1.0, 200 * mm), 125 * um, 1.875 * mm, "square", 1.875 * mm, (5, 5), 5, 3, 525 * nm
)
COLLECTED = (1 - math.sqrt(1 - 0.3**2)) / 2  # power through NA 0.3 of a unit isotropic emitter


def _full_field_pattern(system: ConventionalLFMSystem, z: float, a: int, b: int, reach: int) -> torch.Tensor:
    """Reference: NIP field of the whole region x every lenslet, band-limited ASM to the sensor, pixels."""
    ns = samples_per_pitch(system)
    dx = system.pitch / ns
    n = (2 * reach + 3) * ns
    step = ns // system.voxels_per_lenslet
    m = system.magnification
    # Image-side offset (a, b) sub-positions = object-side (-b, -a) step dx / M (inverted image).
    nip = debye_psf(
        system.objective, Grid(n, dx), system.wavelength, z, position=(-b * step * dx / m, -a * step * dx / m),
        image_side=True, radial_sampling=8, dtype=torch.complex128,
    )  # fmt: skip
    mla = square_grid(system.pitch, system.lenslet_focal_length, count=2 * reach + 3, shape="square")
    field = nip.with_data(
        nip.data * mla_transmission(mla, nip.grid, system.wavelength, dtype=torch.complex128)
    )
    at_sensor = propagate(field, system.mla_to_camera, method="bandlimited_asm")
    canvas = (2 * reach + 3) * system.pixels_per_lenslet
    return integrate_pixels(at_sensor.intensity(), at_sensor.grid, system.pixel_size, shape=(canvas, canvas))


@pytest.mark.parametrize(("z", "a", "b"), [(0.0, 0, 0), (30 * um, -1, 1), (-60 * um, 1, 0)])
def test_pattern_matches_full_field_simulation(z, a, b):
    # Convergence study of the former three-pitch matrix transform (sub-samples per pixel
    # 1 -> 13): error 45 % -> 1.0 / 0.6 / 1.4 %; the floor is the reference's own
    # piecewise-constant 2 um cells. The default oversampling (1.4 samples per intensity
    # Nyquist interval) measured 1.4 / 0.8 / 2.3 % with it, 0.20 / 0.67 / 1.90 % with the FFT
    # transform (oversampling 3: 0.15 / 0.52 / 1.31 %) -> 3 % budget. Adding lenslet
    # intensities instead of fields measured 5-10 % here, so this test tells the two apart.
    reach = SYSTEM.support(z)
    base = nip_fields(SYSTEM, (z,), reach=reach, dtype=torch.float64)
    fast = offset_pattern(SYSTEM, base, a, b, reach=reach, dtype=torch.float64)[0]
    reference = _full_field_pattern(SYSTEM, z, a, b, reach)
    error = float((fast - reference).norm() / reference.norm())
    assert error < 0.03, error
    finer = offset_pattern(SYSTEM, base, a, b, reach=reach, dtype=torch.float64, oversampling=3.0)[0]
    assert float((finer - reference).norm() / reference.norm()) < min(error, 0.02)


@pytest.mark.parametrize("z", [0.0, 40 * um, -80 * um])
def test_every_sub_position_keeps_the_collected_power(z):
    # Unit emitter, aplanatic objective: (1 - cos alpha)/2 reaches the NIP and every lenslet
    # passes all of it (fill factor 1). Errors: light beyond the canvas (on the FFT grid's
    # padding) and the midpoint-rule pixel integration at 1.4 samples per intensity Nyquist
    # interval (either sign) -> 1.5 % budget; measured -0.54 % to -0.37 % (the former
    # three-pitch matrix transform: -0.6 % to +1.2 %).
    patterns = conventional_patterns(SYSTEM, (z,), reach=SYSTEM.support(z), dtype=torch.float64)
    totals = patterns.sum(dim=(-2, -1))[0]
    assert torch.allclose(totals, torch.full_like(totals, COLLECTED), rtol=0.015)


def test_in_focus_point_lights_mostly_its_own_lenslet():
    # In focus all light crosses the source's lenslet; its sub-image is the pupil image,
    # 2 d NA / M = 112.5 um in a 125 um pitch, whose diffraction edge spills ~5 % (the
    # corner sub-positions most) onto neighbouring pixels.
    patterns = conventional_patterns(SYSTEM, (0.0,), reach=SYSTEM.support(0.0), dtype=torch.float64)[0]
    q, h = SYSTEM.pixels_per_lenslet, patterns.shape[-1]
    c = h // 2
    own = patterns[..., c - q // 2 : c + q // 2 + 1, c - q // 2 : c + q // 2 + 1].sum(dim=(-2, -1))
    fraction = own / patterns.sum(dim=(-2, -1))
    assert float(fraction.min()) > 0.9 and float(fraction.max()) < 1.0


def test_symmetry_expansion_equals_direct_computation():
    z = 40 * um
    reach = SYSTEM.support(z)
    base = nip_fields(SYSTEM, (z,), reach=reach, dtype=torch.float64)
    expanded = conventional_patterns(SYSTEM, (z,), reach=reach, dtype=torch.float64, nip_field=base)[0]
    half = SYSTEM.voxels_per_lenslet // 2
    for a, b in [(-1, 0), (1, -1), (-1, -1), (0, 1)]:
        direct = offset_pattern(SYSTEM, base, a, b, reach=reach, dtype=torch.float64)[0]
        assert torch.allclose(expanded[a + half, b + half], direct, rtol=0, atol=1e-12 * float(direct.max()))


def test_nip_field_quadrant_mirror_equals_full_grid():
    z = (25 * um,)
    mirrored = nip_fields(SYSTEM, z, reach=1, dtype=torch.float64)
    n, dx = nip_field_size(SYSTEM, 1), SYSTEM.pitch / samples_per_pitch(SYSTEM)
    table = radial_table_sampling(SYSTEM, dx, 8)
    assert table == 5  # 51 samples per pitch: 2.45 um against the 4.4 um Nyquist step (8 x 0.56)
    direct = debye_psf(
        SYSTEM.objective, Grid(n, dx), SYSTEM.wavelength, torch.tensor(z, dtype=torch.float64),
        image_side=True, radial_sampling=table, dtype=torch.complex128,
    ).data  # fmt: skip
    assert torch.allclose(mirrored, direct, rtol=0, atol=1e-12 * float(direct.abs().max()))


@pytest.fixture(scope="module")
def projector():
    depths = (-40 * um, 0.0, 30 * um)
    return conventional_projector(SYSTEM, depths, dtype=torch.float64)


def test_projector_adjoint_identity(projector):
    A, _ = projector
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(A.volume_shape, generator=gen, dtype=torch.float64)
    y = torch.rand(A.image_shape, generator=gen, dtype=torch.float64)
    lhs = float((A.forward(x) * y).sum())
    rhs = float((x * A.adjoint(y)).sum())
    assert lhs == pytest.approx(rhs, rel=1e-12)


def test_a_single_voxel_projects_its_pattern_inverted(projector):
    # Voxel (z=1, sample row/col k) sits at image-orientation index N-1-k: lenslet j, sub-position p.
    A, stack = projector
    z_index, s, q = 1, SYSTEM.voxels_per_lenslet, SYSTEM.pixels_per_lenslet
    n = A.volume_shape[1]
    volume = torch.zeros(A.volume_shape, dtype=torch.float64)
    k_row, k_col = 3, 9  # sample orientation
    volume[z_index, k_row, k_col] = 1.0
    image = A.forward(volume)
    i_row, i_col = n - 1 - k_row, n - 1 - k_col
    (j_row, p_row), (j_col, p_col) = divmod(i_row, s), divmod(i_col, s)
    pattern = stack.data[p_row, p_col, stack.depths.index(0.0)]
    h = pattern.shape[-1]
    reach_lenslets = h // q // 2
    expected = torch.zeros(A.image_shape, dtype=torch.float64)
    top, left = (j_row - reach_lenslets) * q, (j_col - reach_lenslets) * q
    rows = slice(max(top, 0), min(top + h, A.image_shape[0]))
    cols = slice(max(left, 0), min(left + h, A.image_shape[1]))
    expected[rows, cols] = pattern[rows.start - top : rows.stop - top, cols.start - left : cols.stop - left]
    assert torch.allclose(image, expected, atol=1e-15)


def test_gradcheck_projector():
    small = ConventionalLFMSystem(
        SYSTEM.objective,
        SYSTEM.pitch,
        SYSTEM.lenslet_focal_length,
        "square",
        SYSTEM.mla_to_camera,
        (2, 2),
        3,
        3,
        SYSTEM.wavelength,
    )
    A, _ = conventional_projector(small, (0.0, 20 * um), dtype=torch.float64)
    gen = torch.Generator().manual_seed(1)
    x = torch.rand(A.volume_shape, generator=gen, dtype=torch.float64, requires_grad=True)
    y = torch.rand(A.image_shape, generator=gen, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(A.forward, (x,), fast_mode=True)
    assert torch.autograd.gradcheck(A.adjoint, (y,), fast_mode=True)


def test_preset_maps_to_a_system_and_bad_values_are_named():
    system = conventional_system_of(load_preset("lfm_10x_na03"), lenslets=(41, 41), pixels_per_lenslet=15)
    assert system.voxel_size == pytest.approx(125e-6 / (10 * 5), rel=1e-12)
    with pytest.raises(ValueError, match="pixels_per_lenslet must be an odd integer >= 1; got 14"):
        ConventionalLFMSystem(
            SYSTEM.objective, 125 * um, 1.875 * mm, "square", 1.875 * mm, (5, 5), 14, 3, 525 * nm
        )
    with pytest.raises(ValueError, match="design kind must be 'conventional'"):
        conventional_system_of(load_preset("xlfm_cong2017"))


def test_the_design_lenslet_aperture_reaches_the_system_and_is_checked():
    design = load_preset("lfm_10x_na03")
    assert conventional_system_of(design).lenslet_aperture is None
    assert conventional_system_of(design).aperture == pytest.approx(125e-6, rel=1e-12)
    narrowed = evolve(design, "mla.lenslet_aperture_diameter_um", 100.0)
    assert conventional_system_of(narrowed).lenslet_aperture == pytest.approx(100e-6, rel=1e-12)
    args = (SYSTEM.objective, 125 * um, 1.875 * mm, "square", 1.875 * mm, (5, 5), 15, 3, 525 * nm)
    with pytest.raises(ValueError, match="lenslet_aperture must be at most the pitch"):
        ConventionalLFMSystem(*args, lenslet_aperture=126 * um)
    with pytest.raises(ValueError, match="lenslet_aperture must be a finite number > 0"):
        ConventionalLFMSystem(*args, lenslet_aperture=0.0)
