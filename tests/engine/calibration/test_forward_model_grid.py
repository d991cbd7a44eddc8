"""Lenslet grid on radiometry frames made by the wave-optics forward model (issue 21 bounds).

:func:`forward_model_frames`: the conventional forward model (``lfm_10x_na03``, 23 x 23
lenslets of 19 px, one depth) images a fluorescent plane at focus on its own lattice;
:func:`unrectify` shows it through a raw camera at a non-integer pitch, a rotation and an
offset (a dark rim around the lit block), then 30 % vignetting, a 100 ADU dark offset,
Poisson and read noise and 0.1 % hot pixels are added. The truth is the raw lattice handed
to :func:`unrectify` (the model puts lenslet ``k``'s axis on pixel ``k n + (n - 1) / 2``, the
centre of its middle pixel, which is where :func:`unrectify` maps lattice site ``k``), not a fit.

Bounds: pitch <= 0.01 px per axis, rotation <= 0.02 deg, centres <= 0.1 px RMS.
"""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.calibration import LensletLattice, calibrate
from lfm_studio.engine.calibration.synthetic import conventional_design_for, forward_model_frames

SHAPE = (448, 480)
LENSLETS = 23
CASES = [  # (pitch_y, pitch_x) px, rotation deg, offset of lenslet (0, 0) from the frame centre px
    ((15.38, 15.38), 0.7, (3.3, -5.9)),
    ((17.21, 17.21), 2.0, (-6.1, 2.45)),
]


def _nearest_site(points: torch.Tensor, truth: LensletLattice) -> torch.Tensor:
    """Offset (L, 2) of each point from the nearest true lenslet centre, px."""
    return points - truth.centres(truth.lattice_coordinates(points).round())


@pytest.fixture(scope="module", params=CASES, ids=lambda c: f"pitch{c[0][1]}-rot{c[1]}")
def case(request):
    pitch, rotation, offset = request.param
    centre = ((SHAPE[0] - 1) / 2 + offset[0], (SHAPE[1] - 1) / 2 + offset[1])
    truth = LensletLattice.from_geometry(pitch, math.radians(rotation), centre)
    frames = forward_model_frames(SHAPE, truth, lenslets=LENSLETS, seed=7)
    mean_pitch = sum(pitch) / 2  # the nominal design: same optics, the raw camera's pixels
    design = conventional_design_for(mean_pitch, SHAPE, disk_fraction=frames.disk_diameter / mean_pitch)
    return truth, frames, calibrate(frames.radiometry, design, dark=frames.dark)


def test_truth_is_where_the_forward_model_puts_the_light(case):
    """The geometry's lattice is the light centre of each lit lenslet's cell in the noise-free frame.

    A half-pixel slip between the model's and the calibration's conventions would show as 0.5 px;
    measured 0.00 px on the model's own lattice (19 px, no rotation) and up to 0.045 px here, from
    the resampling by :func:`unrectify` and cells cut along pixel centres.
    """
    truth, frames, _ = case
    ny, nx = SHAPE
    yy, xx = torch.meshgrid(
        torch.arange(ny, dtype=torch.float64), torch.arange(nx, dtype=torch.float64), indexing="ij"
    )
    points = torch.stack((yy, xx), dim=-1).reshape(-1, 2)
    site = truth.lattice_coordinates(points).round().long()
    inner = LENSLETS // 2 - 1  # lit lenslets whose cells lie inside the frame
    light = frames.clean.reshape(-1)
    for ij in ((0, 0), (-inner, inner), (inner, -inner), (3, 5)):
        cell = (site == torch.tensor(ij)).all(dim=1)
        centroid = (points[cell] * light[cell, None]).sum(0) / light[cell].sum()
        expected = truth.centres(torch.tensor(ij))
        assert torch.allclose(centroid, expected, atol=0.05), (ij, centroid, expected)


def test_pitch_rotation_and_centres_within_bounds(case):
    truth, _, calibration = case
    grid = calibration.grid
    fitted = grid.lattice
    assert fitted.pitch[0] == pytest.approx(truth.pitch[0], abs=0.01)
    assert fitted.pitch[1] == pytest.approx(truth.pitch[1], abs=0.01)
    assert math.degrees(fitted.rotation) == pytest.approx(math.degrees(truth.rotation), abs=0.02)
    sites = fitted.centres(grid.indices)
    lit = (truth.lattice_coordinates(sites).round().abs() <= LENSLETS // 2).all(dim=1)  # the lit block
    sites = sites[lit]
    lattice_rms = _nearest_site(sites, truth).pow(2).sum(1).mean().sqrt()
    measured_rms = _nearest_site(grid.measured[grid.used], truth).pow(2).sum(1).mean().sqrt()
    assert lattice_rms <= 0.1
    assert measured_rms <= 0.1
    assert int((grid.used & lit).sum()) >= 0.9 * LENSLETS**2  # the lit lenslets carry the fit
    assert not bool((grid.used & ~lit).any())  # the dark rim's noise centroids are left out (dim)
