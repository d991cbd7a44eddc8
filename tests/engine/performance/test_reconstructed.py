"""Volume-grid settings and the reconstructed two-point resolution (issue 22, items 6-7, ``resolution``)."""

from __future__ import annotations

import json
import warnings

import pytest
import torch

from lfm_studio.engine.design import DepthSpec, DesignError, LensletSpec, MLASpec, load_preset
from lfm_studio.engine.performance.reconstructed import linear_profile, reconstructed_resolution
from lfm_studio.engine.performance.two_point import dip_ratio
from lfm_studio.engine.simulation import imaging_setup, simulate_psf
from lfm_studio.engine.units import um

PIXEL_UM = 13.0  # large pixels: the spots (1.22 lambda d / D = 17 um) span ~1.3 px, so the grid limits


def sampling_limited_design(
    volume_oversampling: int = 1, pixels: int = 96, *, pixel_um: float = PIXEL_UM, offset_um: float = 450.0,
    aperture_um: float = 800.0,
):  # fmt: skip
    """A Fourier LFM whose camera pixel, not diffraction, limits the reachable resolution.

    Guo's optics (40x/0.95, f_F 75 mm, d 16.8 mm, 680 nm) with 4 lenslets of 800 um, 13 um
    pixels: M_T = 8.96, voxel 13 / 8.96 = 1.45 um, diffraction 0.61 lambda / NA_eff with
    NA_eff = 0.95 x 800 / 3562.5 = 0.213: 1.94 um, below the coarse grid floor 2.9 um.
    """
    base = load_preset("flfm_guo2019")
    lenslets = tuple(
        LensletSpec(center_um=(x, y), aperture_diameter_um=aperture_um, focal_length_mm=16.8)
        for y in (-offset_um, offset_um)
        for x in (-offset_um, offset_um)
    )
    return base.updated(
        camera={**base.camera.model_dump(), "pixel_count": (pixels, pixels), "pixel_pitch_um": pixel_um},
        depths=DepthSpec(depth_range_um=(-10.0, 10.0), depth_step_um=2.0),
        relay={"focal_length_mm": 75.0, "field_stop_diameter_mm": 0.5},
        mla=MLASpec(lenslets=lenslets),
        accuracy={"preset": "preview", "volume_oversampling": volume_oversampling},
    )


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # sampling / design advisories of the small test designs
        yield


# -- settings ------------------------------------------------------------------------------
def test_grid_settings_default_validate_and_survive_json():
    design = load_preset("lfm_prevedel2014")
    assert design.accuracy.voxels_per_lenslet == 5 and design.accuracy.volume_oversampling == 1
    for key, value, message in (
        ("voxels_per_lenslet", 4, r"voxels_per_lenslet must be an odd integer >= 1 .*; got 4"),
        ("voxels_per_lenslet", 0, r"voxels_per_lenslet must be an odd integer >= 1 .*; got 0"),
        ("volume_oversampling", 2, "volume_oversampling must be 1, 3, 5 or 7"),
    ):
        with pytest.raises((DesignError, ValueError), match=message):
            design.updated(accuracy={**design.accuracy.model_dump(), key: value})
    finer = design.updated(accuracy={**design.accuracy.model_dump(), "voxels_per_lenslet": 7})
    back = type(design).model_validate(json.loads(finer.model_dump_json()))
    assert back.accuracy.voxels_per_lenslet == 7 and back.accuracy.matches_preset()


def test_conventional_stack_and_volume_follow_voxels_per_lenslet():
    # voxel = pitch / (M s): 125 um / (10 x 7) for s = 7 (independent of the engine's formula)
    base = load_preset("lfm_10x_na03")
    design = base.updated(
        accuracy={**base.accuracy.model_dump(), "preset": "preview", "voxels_per_lenslet": 7}
    )
    stack = simulate_psf(design, depths=(0.0,), crop=60)
    assert stack.patterns is not None and stack.patterns.voxels_per_lenslet == 7
    setup = imaging_setup(stack)
    assert setup.voxel_size[1] == pytest.approx(125 * um / (10 * 7), rel=1e-9)


@pytest.mark.parametrize("pixels", [128, 127], ids=["even", "odd"])
def test_refined_fourier_psf_bins_to_the_camera_psf(pixels):
    # Pixel power is an area integral: summing the 3 x 3 virtual pixels of each camera pixel must give
    # the camera's own PSF (two simulations on different grids; preview accuracy, 6.5 um pixels that
    # sample the spots well: measured 1.2e-3).
    well_sampled = dict(pixel_um=6.5, offset_um=300.0, aperture_um=500.0)
    coarse = simulate_psf(sampling_limited_design(1, pixels, **well_sampled), depths=(0.0, 4e-6))
    fine = simulate_psf(sampling_limited_design(3, pixels, **well_sampled), depths=(0.0, 4e-6))
    assert fine.volume_oversampling == 3 and "volume_oversampling" not in fine.metadata
    assert fine.pixel_size == pytest.approx(coarse.pixel_size / 3, rel=1e-12)
    n = pixels
    binned = fine.data[:, : 3 * n, : 3 * n].reshape(2, n, 3, n, 3).sum(dim=(2, 4))
    assert float((binned - coarse.data).norm() / coarse.data.norm()) < 5e-3
    # The binned projector: fine voxel 3 x finer; a point on a shared voxel centre images alike; exact adjoint.
    sc, sf = imaging_setup(coarse), imaging_setup(fine)
    assert sf.voxel_size[1] == pytest.approx(sc.voxel_size[1] / 3, rel=1e-12)
    assert sf.projector.image_shape == sc.projector.image_shape == (n, n)
    vc, vf = torch.zeros(sc.volume_shape), torch.zeros(sf.volume_shape)
    (_, cy, cx), (_, fy, fx) = (
        tuple(s // 2 for s in sc.volume_shape),
        tuple(s // 2 for s in sf.volume_shape),
    )
    vc[1, cy + 2, cx - 1] = 1.0
    vf[1, fy + 6, fx - 3] = 1.0
    a, b = sc.projector.forward(vc), sf.projector.forward(vf)
    assert float((a - b).norm() / a.norm()) < 5e-3
    y = torch.rand(a.shape, generator=torch.Generator().manual_seed(1))
    vr = torch.rand(sf.volume_shape, generator=torch.Generator().manual_seed(2))
    lhs, rhs = float((sf.projector.forward(vr) * y).sum()), float((vr * sf.projector.adjoint(y)).sum())
    assert lhs == pytest.approx(rhs, rel=1e-5)


# -- reconstructed resolution -------------------------------------------------------------
def test_neighbouring_voxels_never_show_a_dip():
    # The grid floor: between two adjacent samples a linear interpolant has no value below the
    # smaller end, whatever the values; two voxels apart a low middle voxel is a dip.
    values = torch.rand(50, generator=torch.Generator().manual_seed(0)) + 0.1
    profile = linear_profile(values)
    for i in range(49):
        between = profile(torch.linspace(i, i + 1, 101, dtype=torch.float64))
        assert float(between.min()) >= min(float(values[i]), float(values[i + 1])) - 1e-7
    constructed = torch.tensor([0.0, 1.0, 0.5, 1.0, 0.0])
    # (the maxima are read on dip_ratio's 401-point sampling, 0.1 % below the voxel values)
    assert dip_ratio(linear_profile(constructed), 1.0, 3.0) == pytest.approx(0.5, rel=2e-3)


def test_a_finer_fourier_grid_resolves_below_the_coarse_grid_floor():
    # Grid floor derived here: 2 voxels = 2 x pixel / M_T, with M_T = 40 x 16.8 / 75.
    m_t = 40 * 16.8 / 75
    floor_coarse, floor_fine = 2 * PIXEL_UM * um / m_t, 2 * PIXEL_UM * um / (3 * m_t)
    options = dict(iterations=30, crop=None, max_lateral=6 * um, max_axial=4 * um)
    coarse = reconstructed_resolution(sampling_limited_design(1), (0.0,), **options)
    fine = reconstructed_resolution(sampling_limited_design(3), (0.0,), **options)
    assert coarse.lateral_grid_floor == pytest.approx(floor_coarse, rel=1e-9)
    assert fine.lateral_grid_floor == pytest.approx(floor_fine, rel=1e-9)
    (c,), (f,) = coarse.depths, fine.depths
    assert c.lateral is not None and f.lateral is not None
    assert c.lateral >= floor_coarse * (1 - 1e-9) and f.lateral >= floor_fine * (1 - 1e-9)
    # The optics (0.61 lambda / NA_eff = 1.94 um) allow a pair that the coarse grid cannot show.
    assert f.lateral < floor_coarse * (1 - 1e-9) <= c.lateral
    assert all(dip >= 0.735 for s, dip in f.lateral_dips if s < f.lateral)
    data = fine.to_dict()
    assert data["depths"][0]["lateral_um"] == pytest.approx(f.lateral / um)
    assert data["lateral_grid_floor_um"] == pytest.approx(floor_fine / um)


def test_conventional_resolution_is_finite_at_or_above_its_floor_and_improves_with_the_grid():
    base = load_preset("lfm_10x_na03")
    results = {}
    for s in (3, 5):
        design = base.updated(
            accuracy={**base.accuracy.model_dump(), "preset": "preview", "voxels_per_lenslet": s}
        )
        report = reconstructed_resolution(
            design,
            (20 * um,),
            iterations=20,
            crop=60,
            max_lateral=12 * um,
            max_axial=8 * um,
            depth_step=4 * um,
        )
        (depth,) = report.depths
        floor = 2 * 125 * um / (10 * s)  # 2 voxels of pitch / (M s)
        assert depth.lateral is not None and depth.lateral >= floor * (1 - 1e-9)
        results[s] = depth.lateral
    assert results[5] <= results[3]


def test_bad_arguments_are_named():
    design = sampling_limited_design(1)
    with pytest.raises(ValueError, match="iterations must be an integer >= 1; got 0"):
        reconstructed_resolution(design, (0.0,), iterations=0)
    with pytest.raises(ValueError, match="max_lateral must be > 0 m"):
        reconstructed_resolution(design, (0.0,), max_lateral=0.0)
    with pytest.raises(ValueError, match="photons must be > 0"):
        reconstructed_resolution(design, (0.0,), photons=-1.0)
    # XLFM has no lenslet on the axis: its per-lenslet PSF leaves a 16 px centre dark.
    with pytest.raises(ValueError, match="no light reaches the central 16 x 16 pixel crop"):
        reconstructed_resolution(
            load_preset("xlfm_cong2017"), (0.0,), crop=16, iterations=1, max_axial=2 * um
        )
