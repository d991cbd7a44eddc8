"""The MLA cell grid: blocks, symmetry orbits, merges and conversion to design lenslets."""

from __future__ import annotations

import math
import warnings

import pytest

from lfm_studio.engine.design import DesignError, load_preset
from lfm_studio.engine.optimize.mla_cells import SYMMETRIES, Block, MLAPlane, merge, orbit


@pytest.fixture(scope="module")
def xlfm():
    return load_preset("xlfm_cong2017")


def _cells(block: Block) -> set[tuple[int, int]]:
    return {(block.i + a, block.j + b) for a in range(block.size) for b in range(block.size)}


def test_overlap_and_containment_agree_with_cell_sets():
    blocks = [Block(i, j, s) for i in range(4) for j in range(4) for s in (1, 2, 3)]
    for a in blocks:
        for b in blocks:
            assert a.overlaps(b) == bool(_cells(a) & _cells(b))
            assert a.contains(b) == (_cells(b) <= _cells(a))


@pytest.mark.parametrize("cells", [5, 6])
def test_orbits_map_cells_onto_their_mirror_and_rotated_cells(cells):
    # Independent reference: transform every cell centre (i + 1/2 - M/2) and compare cell sets.
    def image(block, fn):
        out = set()
        for i, j in _cells(block):
            x, y = fn(2 * i + 1 - cells, 2 * j + 1 - cells)
            out.add(((x + cells - 1) // 2, (y + cells - 1) // 2))
        return frozenset(out)

    groups = {
        "none": [lambda x, y: (x, y)],
        "mirror": [lambda x, y: (x, y), lambda x, y: (-x, y)],
        "mirror-xy": [lambda x, y: (x, y), lambda x, y: (-x, y), lambda x, y: (x, -y), lambda x, y: (-x, -y)],
        "4-fold": [lambda x, y: (x, y), lambda x, y: (-y, x), lambda x, y: (-x, -y), lambda x, y: (y, -x)],
    }
    groups["8-fold"] = groups["4-fold"] + [
        lambda x, y: (-x, y), lambda x, y: (x, -y), lambda x, y: (y, x), lambda x, y: (-y, -x),
    ]  # fmt: skip
    assert set(groups) == set(SYMMETRIES)
    for symmetry, fns in groups.items():
        for block in (Block(0, 0, 1), Block(1, 0, 2), Block(0, 1, 3), Block(1, 1, cells - 2)):
            expected = {image(block, fn) for fn in fns}
            got = {frozenset(_cells(b)) for b in orbit(block, cells, symmetry)}
            assert got == expected, (symmetry, block)


def test_orbit_sizes():
    assert orbit(Block(2, 2, 2), 6, "8-fold") == (Block(2, 2, 2),)  # centred: its own image
    assert len(orbit(Block(0, 0, 1), 6, "4-fold")) == 4  # a corner visits the four corners
    assert len(orbit(Block(0, 1, 1), 6, "8-fold")) == 8
    assert orbit(Block(0, 2, 1), 5, "mirror") == (Block(0, 2, 1), Block(4, 2, 1))
    with pytest.raises(ValueError, match="symmetry must be one of"):
        orbit(Block(0, 0, 1), 5, "6-fold")


def test_merge_absorbs_contained_lenslets_and_refuses_conflicts():
    state = tuple(Block(i, j, 1) for i in range(4) for j in range(4))
    merged, reason = merge(state, [Block(1, 1, 2)])
    assert reason == ""
    assert len(merged) == 16 - 4 + 1 and Block(1, 1, 2) in merged
    assert merged == tuple(sorted(merged))
    # A 2x2 block that half-covers the merged one cuts through it.
    again, reason = merge(merged, [Block(2, 1, 2)])
    assert again == () and reason.startswith("conflict")
    # A 3x3 block containing the 2x2 absorbs it and its neighbours.
    bigger, reason = merge(merged, [Block(0, 0, 3)])
    assert reason == "" and len(bigger) == 16 - 9 + 1
    # Two images of one block that overlap each other: a symmetry conflict.
    _, reason = merge(state, [Block(1, 0, 2), Block(0, 0, 2)])
    assert reason.startswith("symmetry conflict")


def test_plane_from_design_counts_cells_and_keeps_lenslets_in_the_pupil(xlfm):
    pupil_um = xlfm.pupil_diameter_at_mla / 1e-6
    plane = MLAPlane.from_design(xlfm, 2000.0)
    assert plane.cells == math.floor(pupil_um / 2000.0) == 8
    assert plane.focal_lengths_mm == (26.0, 28.5)
    blocks = plane.initial_blocks()
    # Independent count: cell centres at odd multiples of 1000 um, circle radius 1000 um.
    expected = {
        (i, j)
        for i in range(8)
        for j in range(8)
        if math.hypot((2 * i - 7) * 1000.0, (2 * j - 7) * 1000.0) + 1000.0 <= pupil_um / 2 + 1e-6
    }
    assert {(b.i, b.j) for b in blocks} == expected and all(b.size == 1 for b in blocks)
    assert plane.outside_reason(Block(0, 0, 1)).startswith("Block(i=0, j=0, size=1) reaches")
    assert "not on the 8 x 8 cell grid" in plane.outside_reason(Block(7, 7, 2))


def test_lenslets_sit_at_block_centres_and_build_a_valid_design(xlfm):
    plane = MLAPlane.from_design(xlfm, 2000.0)
    blocks, reason = merge(plane.initial_blocks(), [Block(2, 2, 4)])
    assert reason == ""
    lenslets = plane.lenslets(blocks)
    big = next(lens for lens in lenslets if lens.aperture_diameter_um == 8000.0)
    assert big.center_um == (0.0, 0.0)
    small = plane.lenslets([Block(0, 3, 1)])[0]
    assert small.center_um == (-7000.0, -1000.0) and small.aperture_diameter_um == 2000.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # overlapping sub-images are a design warning here
        design = plane.design_with(xlfm, blocks)
    assert design.mla.count == len(blocks)
    assert sum(lens.aperture_diameter_um**2 for lens in design.mla.lenslets) == pytest.approx(
        (len(blocks) - 1) * 2000.0**2 + 8000.0**2
    )


def test_focal_rule_is_the_same_on_every_symmetric_image(xlfm):
    plane = MLAPlane.from_design(xlfm, 2000.0)
    for block in plane.initial_blocks():
        focal = {plane.focal_length_mm(b) for b in orbit(block, plane.cells, "8-fold")}
        assert len(focal) == 1
    rings = {round(math.hypot(*plane.center_um(b)) / 2000.0) for b in plane.initial_blocks()}
    used = {plane.focal_length_mm(b) for b in plane.initial_blocks()}
    assert len(rings) > 1 and used == {26.0, 28.5}


def test_bad_inputs_name_the_parameter(xlfm):
    conventional = load_preset("lfm_prevedel2014")
    with pytest.raises(DesignError, match="plane_diameter_um"):
        MLAPlane.from_design(conventional, 100.0)
    assert MLAPlane.from_design(conventional, 100.0, plane_diameter_um=1000.0).cells == 10
    with pytest.raises(ValueError, match="min_lenslet_um"):
        MLAPlane.from_design(xlfm, 0.0)
    with pytest.raises(ValueError, match="focal_lengths_mm"):
        MLAPlane(1000.0, 4, 4000.0, ())
    with pytest.raises(ValueError, match="pupil_diameter_um"):
        MLAPlane(1000.0, 4, float("nan"), (3.0,))
    with pytest.raises(ValueError, match="shape"):
        MLAPlane(1000.0, 4, 4000.0, (3.0,), "hexagon")
