"""Microlens arrays: grid helpers (count, pitch, symmetry), overlap and aperture checks, both MLA forms."""

from __future__ import annotations

import math

import pytest

from lfm_studio.engine.design import LensletSpec, MLASpec, RegularMLASpec


def _nearest_distances(centers):
    return [min(math.dist(c, o) for o in centers if o is not c) for c in centers]


def _assert_point_symmetric(centers, about=(0.0, 0.0)):
    """Every centre has its mirror image through ``about`` in the set (to 1e-6 um: the stored rounding)."""
    for x, y in centers:
        mirror = (2 * about[0] - x, 2 * about[1] - y)
        assert min(math.dist(mirror, c) for c in centers) < 1e-6


@pytest.mark.parametrize(("shape", "count"), [(1, 1), (3, 9), (4, 16), ((2, 5), 10)])
def test_square_grid_count_pitch_and_symmetric_centres(shape, count):
    mla = MLASpec.square_grid(150.0, shape, 3.0, fill_factor=0.9)
    centers = [lens.center_um for lens in mla.lenslets]
    assert mla.count == count
    assert all(lens.aperture_diameter_um == pytest.approx(135.0, rel=1e-12) for lens in mla.lenslets)
    if count > 1:  # every lenslet has a neighbour exactly one pitch away (1e-6 um: centre rounding)
        assert _nearest_distances(centers) == pytest.approx([150.0] * count, abs=1e-6)
    _assert_point_symmetric(centers)
    # Centred: the mean centre is the axis (exact up to the 1e-6 um rounding).
    assert sum(c[0] for c in centers) / count == pytest.approx(0.0, abs=1e-9)
    assert sum(c[1] for c in centers) / count == pytest.approx(0.0, abs=1e-9)


def test_square_grid_order_is_row_by_row_and_offset_moves_it():
    mla = MLASpec.square_grid(100.0, (2, 3), 2.0, offset_um=(10.0, -20.0))
    assert [lens.center_um for lens in mla.lenslets] == [
        (-90.0, -70.0), (10.0, -70.0), (110.0, -70.0), (-90.0, 30.0), (10.0, 30.0), (110.0, 30.0),
    ]  # fmt: skip


@pytest.mark.parametrize(("rings", "count"), [(0, 1), (1, 7), (2, 19), (3, 37)])
def test_hex_grid_rings_count_pitch_and_six_fold_symmetry(rings, count):
    mla = MLASpec.hex_grid(200.0, 5.0, rings=rings)
    centers = [lens.center_um for lens in mla.lenslets]
    assert mla.count == count == 1 + 3 * rings * (rings + 1)
    if count > 1:
        assert _nearest_distances(centers) == pytest.approx([200.0] * count, abs=1e-6)
        # The central lenslet has exactly six neighbours at one pitch.
        assert sum(1 for c in centers if abs(math.dist(c, (0.0, 0.0)) - 200.0) < 1e-6) == 6
    for angle in (math.pi / 3, math.pi):  # rotation by 60 degrees maps the patch onto itself
        rotated = [
            (x * math.cos(angle) - y * math.sin(angle), x * math.sin(angle) + y * math.cos(angle))
            for x, y in centers
        ]
        for point in rotated:
            assert min(math.dist(point, c) for c in centers) < 1e-5


def test_hex_grid_rows_and_argument_checks():
    mla = MLASpec.hex_grid(100.0, 2.0, shape=(3, 4))
    centers = [lens.center_um for lens in mla.lenslets]
    assert mla.count == 12
    assert _nearest_distances(centers) == pytest.approx([100.0] * 12, abs=1e-6)
    rows = sorted({y for _, y in centers})
    assert rows == pytest.approx([-100 * math.sqrt(3) / 2, 0.0, 100 * math.sqrt(3) / 2], abs=1e-6)
    assert (min(x for x, _ in centers) + max(x for x, _ in centers)) == pytest.approx(
        0.0, abs=1e-9
    )  # centred
    with pytest.raises(ValueError, match=r"give exactly one of rings or shape"):
        MLASpec.hex_grid(100.0, 2.0, rings=1, shape=(3, 3))
    with pytest.raises(ValueError, match=r"rings must be an integer >= 0; got -1"):
        MLASpec.hex_grid(100.0, 2.0, rings=-1)


def test_keep_within_diameter_keeps_lenslets_entirely_inside_the_circle():
    # Guo et al. 2019: pupil image 3.5625 mm on a 600 um square-lenslet array; of a 5 x 5 grid the
    # four corner lenslets poke out (corner reach 1.5 sqrt(2) mm > 1.78 mm), the other 21 fit.
    mla = MLASpec.square_grid(600.0, 5, 16.8, lenslet_shape="square", keep_within_diameter_um=3562.5)
    assert mla.count == 21
    assert all(lens.reach_um <= 3562.5 / 2 for lens in mla.lenslets)
    with pytest.raises(ValueError, match=r"no lenslet fits inside keep_within_diameter_um 100 um"):
        MLASpec.square_grid(600.0, 5, 16.8, keep_within_diameter_um=100.0)


def test_overlapping_lenslets_error_names_both_by_index_and_centre():
    lenslets = (
        LensletSpec(center_um=(0.0, 0.0), aperture_diameter_um=150.0, focal_length_mm=3.0),
        LensletSpec(center_um=(500.0, 0.0), aperture_diameter_um=150.0, focal_length_mm=3.0),
        LensletSpec(center_um=(600.0, 20.0), aperture_diameter_um=150.0, focal_length_mm=3.0),
    )
    with pytest.raises(
        ValueError,
        match=r"lenslet 1 \(centre \(500, 0\) um\) and lenslet 2 \(centre \(600, 20\) um\) overlap by 48\.0196 um",
    ):
        MLASpec(lenslets=lenslets)
    # Touching is allowed (centres one diameter apart), for circles and squares alike.
    for shape in ("circle", "square"):
        touching = [
            LensletSpec(center_um=(x, 0.0), aperture_diameter_um=150.0, focal_length_mm=3.0, shape=shape)
            for x in (0.0, 150.0)
        ]
        assert MLASpec(lenslets=tuple(touching)).count == 2


def test_square_apertures_overlap_diagonally_where_circles_do_not():
    def pair(shape):
        return tuple(
            LensletSpec(center_um=c, aperture_diameter_um=100.0, focal_length_mm=1.0, shape=shape)
            for c in [(0.0, 0.0), (90.0, 90.0)]
        )

    assert MLASpec(lenslets=pair("circle")).count == 2  # circles 127 um apart
    with pytest.raises(ValueError, match=r"lenslet 0 .* and lenslet 1 .* overlap by 10 um"):
        MLASpec(lenslets=pair("square"))


def test_lenslets_must_lie_inside_the_array_aperture():
    with pytest.raises(
        ValueError,
        match=r"inside the array aperture of radius 200 um .*lenslet [0-9]+ \(centre \(-150, -150\) um\) reaches",
    ):
        MLASpec.square_grid(150.0, 3, 3.0, array_aperture_diameter_um=400.0)
    assert MLASpec.square_grid(
        150.0, 3, 3.0, array_aperture_diameter_um=600.0
    ).array_aperture_diameter == pytest.approx(6e-4, rel=1e-12)
    with pytest.raises(ValueError, match=r"lenslets must hold at least one lenslet"):
        MLASpec(lenslets=())


def test_multifocal_hex_builds_interleaved_focal_groups_with_complete_shells():
    mla = MLASpec.multifocal_hex(2200.0, 27, (26.0, 28.5), aperture_diameter_um=1000.0, center="triangle")
    focal = [lens.focal_length_mm for lens in mla.lenslets]
    assert mla.count == 27 and mla.focal_lengths_mm == (26.0, 28.5)
    assert (focal.count(26.0), focal.count(28.5)) == (15, 12)  # the 15 + 12 split of Cong et al. 2017
    centers = [lens.center_um for lens in mla.lenslets]
    assert min(_nearest_distances(centers)) == pytest.approx(2200.0, abs=1e-6)
    for group in (26.0, 28.5):  # each group spreads over the pupil: its centroid is near the axis
        xs = [c for c, f in zip(centers, focal, strict=True) if f == group]
        assert math.hypot(sum(x for x, _ in xs) / len(xs), sum(y for _, y in xs) / len(xs)) < 2200.0 / 2
    with pytest.raises(
        ValueError, match=r"count 25 splits a shell .* complete-shell counts are 3, 6, 12, 18, 21, 27"
    ):
        MLASpec.multifocal_hex(2200.0, 25, (26.0, 28.5), aperture_diameter_um=1000.0, center="triangle")
    centred = MLASpec.multifocal_hex(1000.0, 19, (5.0,), aperture_diameter_um=1000.0)
    assert centred.lenslets[0].center_um == (0.0, 0.0) and centred.count == 19


def test_regular_mla_expands_to_the_same_lenslets_as_the_explicit_helper():
    regular = RegularMLASpec(pitch_um=150.0, shape=(4, 5), focal_length_mm=3.0, lenslet_shape="circle")
    explicit = MLASpec.square_grid(150.0, (4, 5), 3.0)
    assert regular.lenslets == explicit.lenslets
    assert regular.count == 20 and regular.to_explicit() == explicit
    hexagonal = RegularMLASpec(
        lattice="hex", pitch_um=100.0, shape=(3, 4), focal_length_mm=2.0, lenslet_shape="circle"
    )
    assert hexagonal.lenslets == MLASpec.hex_grid(100.0, 2.0, shape=(3, 4)).lenslets


def test_regular_mla_checks_overlap_from_its_neighbourhood():
    with pytest.raises(
        ValueError, match=r"lenslet 0 \(centre \(-75, -75\) um\) and lenslet 1 .* overlap by 10 um"
    ):
        RegularMLASpec(pitch_um=150.0, shape=(2, 2), focal_length_mm=3.0, lenslet_aperture_diameter_um=160.0)
    # Squares on a hexagonal lattice overlap the next row once their side exceeds pitch * sqrt(3) / 2.
    with pytest.raises(ValueError, match=r"overlap"):
        RegularMLASpec(
            lattice="hex", pitch_um=100.0, shape=(3, 3), focal_length_mm=2.0, lenslet_shape="square"
        )
    with pytest.raises(ValueError, match=r"shape must be \(ny, nx\) with both >= 1; got \(0, 3\)"):
        RegularMLASpec(pitch_um=150.0, shape=(0, 3), focal_length_mm=3.0)
    with pytest.raises(ValueError, match=r"pitch_um must be a finite number > 0 um; got -150 um"):
        RegularMLASpec(pitch_um=-150.0, shape=(3, 3), focal_length_mm=3.0)


def test_a_large_regular_array_validates_without_expanding():
    mla = RegularMLASpec(pitch_um=125.0, shape=(400, 400), focal_length_mm=1.875)
    assert mla.count == 160_000
    assert "lenslets" not in mla.__dict__  # the lenslets are built only on first use


@pytest.mark.parametrize("rings", [0, 1, 2, 4])
@pytest.mark.parametrize("fill", [0.6, 1.0])
def test_rings_lattice_count_symmetry_and_no_overlap(rings, fill):
    """Lattice "rings": 1 + 3 r (r + 1) lenslets on concentric hexagonal rings, r = (ny - 1) / 2,
    point- and six-fold symmetric about the centre, nearest neighbours one pitch apart, and no
    overlap at any fill factor <= 1 (the design's own overlap check passes, and is re-done here)."""
    side = 2 * rings + 1
    mla = RegularMLASpec(
        lattice="rings", pitch_um=100.0, shape=(side, side), focal_length_mm=2.0,
        lenslet_aperture_diameter_um=100.0 * fill,
    )  # fmt: skip
    centers = [lens.center_um for lens in mla.lenslets]
    assert mla.rings == rings and mla.count == len(centers) == 1 + 3 * rings * (rings + 1)
    assert len(set(centers)) == len(centers)
    assert (0.0, 0.0) in centers
    _assert_point_symmetric(centers)
    for x, y in centers:  # six-fold: each centre rotated by 60 degrees is a centre
        c, s = math.cos(math.pi / 3), math.sin(math.pi / 3)
        assert min(math.dist((c * x - s * y, s * x + c * y), o) for o in centers) < 1e-5
    if rings:
        assert min(_nearest_distances(centers)) == pytest.approx(100.0, abs=1e-5)
        assert max(math.hypot(*p) for p in centers) == pytest.approx(100.0 * rings, abs=1e-5)
    MLASpec(lenslets=mla.lenslets)  # the explicit form's full pairwise overlap check agrees
    assert mla.lenslets == MLASpec.hex_grid(100.0, 2.0, rings=rings, fill_factor=fill).lenslets


def test_rings_lattice_shape_rule_and_offset():
    with pytest.raises(
        ValueError, match=r"shape must be \(2 r \+ 1, 2 r \+ 1\) for lattice 'rings'.*got \(4, 5\)"
    ):
        RegularMLASpec(lattice="rings", pitch_um=100.0, shape=(4, 5), focal_length_mm=2.0)
    with pytest.raises(ValueError, match=r"got \(4, 4\)\. Fix: e\.g\. \(3, 3\) for 1 ring\(s\), 7 lenslets"):
        RegularMLASpec(lattice="rings", pitch_um=100.0, shape=(4, 4), focal_length_mm=2.0)
    with pytest.raises(ValueError, match="overlap by 10 um"):
        RegularMLASpec(
            lattice="rings",
            pitch_um=100.0,
            shape=(3, 3),
            focal_length_mm=2.0,
            lenslet_aperture_diameter_um=110.0,
        )
    moved = RegularMLASpec(
        lattice="rings", pitch_um=100.0, shape=(3, 3), focal_length_mm=2.0, offset_um=(10.0, -5.0)
    )
    assert (10.0, -5.0) in [lens.center_um for lens in moved.lenslets]
    _assert_point_symmetric([lens.center_um for lens in moved.lenslets], about=(10.0, -5.0))


def test_lattices_are_listed_once():
    from typing import get_args

    from lfm_studio.engine.design import LATTICES

    assert LATTICES == ("square", "hex", "rings")
    assert get_args(RegularMLASpec.model_fields["lattice"].annotation) == LATTICES
    with pytest.raises(ValueError, match="'square', 'hex' or 'rings'"):
        RegularMLASpec(lattice="spiral", pitch_um=100.0, shape=(3, 3), focal_length_mm=2.0)
