"""LensletLattice: geometry round trips against closed forms."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.calibration import LensletLattice


def test_from_geometry_reports_its_pitch_and_rotation():
    lattice = LensletLattice.from_geometry((17.21, 15.38), math.radians(1.7), (10.0, 20.0))
    assert lattice.pitch == pytest.approx((17.21, 15.38), abs=1e-12)
    assert math.degrees(lattice.rotation) == pytest.approx(1.7, abs=1e-12)
    assert lattice.shear == pytest.approx(0.0, abs=1e-12)
    assert lattice.determinant == pytest.approx(17.21 * 15.38, rel=1e-12)


def test_centres_and_lattice_coordinates_are_inverse():
    lattice = LensletLattice.from_geometry((15.38, 15.38), math.radians(-2.0), (100.3, 99.1))
    ij = torch.tensor([[0, 0], [3, -2], [-7, 11]])
    centres = lattice.centres(ij)
    # (i, j) = (3, -2): centre = origin + 3 p (cos, -sin) - 2 p (sin, cos) in (y, x) (closed form).
    p, s, c = 15.38, math.sin(math.radians(-2.0)), math.cos(math.radians(-2.0))
    expected = [100.3 + 3 * p * c - 2 * p * s, 99.1 - 3 * p * s - 2 * p * c]
    assert centres[1].tolist() == pytest.approx(expected, abs=1e-9)
    assert torch.allclose(lattice.lattice_coordinates(centres), ij.double(), atol=1e-9)


def test_recentred_moves_the_origin_to_the_nearest_site():
    lattice = LensletLattice.from_geometry((15.0, 15.0), 0.0, (3.0, 4.0))
    moved = lattice.recentred((100.0, 100.0))
    assert moved.origin == pytest.approx((93.0, 94.0))  # sites 3 + 15 k and 4 + 15 k
    assert moved.row_vector == lattice.row_vector


def test_indices_inside_keeps_only_whole_cells():
    lattice = LensletLattice.from_geometry((10.0, 10.0), 0.0, (4.5, 4.5))  # cells exactly tile 0..99
    indices = lattice.indices_inside((100, 100))
    assert indices.shape[0] == 100
    assert indices.min().item() == 0 and indices.max().item() == 9


def test_parallel_vectors_are_refused():
    with pytest.raises(ValueError, match="parallel"):
        LensletLattice(origin=(0, 0), row_vector=(1.0, 1.0), col_vector=(2.0, 2.0))
