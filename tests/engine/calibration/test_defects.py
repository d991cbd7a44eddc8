"""Dark subtraction, hot/dead pixels and their median replacement, on constructed frames."""

from __future__ import annotations

import math

import pytest
import torch

from lfm_studio.engine.calibration import LensletLattice
from lfm_studio.engine.calibration.defects import (
    dead_pixels,
    hot_pixels,
    median3x3,
    replace_defects,
    subtract_dark,
)
from lfm_studio.engine.calibration.synthetic import synthetic_frames


@pytest.fixture(scope="module")
def frames():
    truth = LensletLattice.from_geometry((15.38, 15.38), math.radians(1.0), (150.0, 160.0))
    return synthetic_frames((320, 336), truth, disk_diameter=13.8, hot_fraction=2e-3, seed=11)


def _isolated(mask: torch.Tensor) -> torch.Tensor:
    """Pixels of ``mask`` none of whose 8 neighbours is in ``mask``."""
    count = torch.nn.functional.conv2d(
        mask[None, None].double(), torch.ones(1, 1, 3, 3, dtype=torch.float64), padding=1
    )
    return mask & (count[0, 0] == 1)


def test_subtract_dark_frame_and_level():
    frame = torch.full((4, 5), 110.0)
    assert torch.equal(subtract_dark(frame, 100.0), torch.full((4, 5), 10.0, dtype=torch.float64))
    assert torch.equal(
        subtract_dark(frame, torch.full((4, 5), 30.0)), torch.full((4, 5), 80.0, dtype=torch.float64)
    )
    with pytest.raises(ValueError, match=r"dark frame shape \(4, 4\).*\(4, 5\).*Fix"):
        subtract_dark(frame, torch.zeros(4, 4))


def test_hot_pixels_in_the_dark_frame(frames):
    found = hot_pixels(frames.dark)
    isolated = _isolated(frames.hot)
    assert bool(found[isolated].all())  # every isolated hot pixel
    assert int((found & ~frames.hot).sum()) == 0  # and nothing else


def test_hot_pixels_in_the_lit_frame_ignore_shot_noise_and_disk_edges(frames):
    lit = frames.radiometry - 100.0
    found = hot_pixels(lit, relative=0.25)
    assert bool(found[_isolated(frames.hot)].all())
    assert int((found & ~frames.hot).sum()) == 0
    # Without the relative test, shot noise on 2000 e- disks is taken for hot pixels: the test matters.
    assert int((hot_pixels(lit) & ~frames.hot).sum()) > 10


def test_dead_pixels_inside_disks_not_in_the_gaps(frames):
    lit = (frames.radiometry - 100.0).clone()
    lattice = frames.lattice
    centres = lattice.centres(torch.tensor([[0, 0], [2, -3], [-4, 5]])).round().long()
    lit[centres[:, 0], centres[:, 1]] = 0.0
    found = dead_pixels(lit)
    assert bool(found[centres[:, 0], centres[:, 1]].all())
    assert int(found.sum()) == 3


def test_replacement_is_exact_on_a_linear_ramp():
    xx = torch.arange(30.0).expand(20, 30)
    ramp = 3.0 * xx + 100.0
    defects = torch.zeros(20, 30, dtype=torch.bool)
    defects[5, 7] = defects[12, 20] = defects[12, 21] = True  # two adjacent defects too
    broken = torch.where(defects, torch.full_like(ramp, 9999.0), ramp)
    repaired = replace_defects(broken, defects)
    assert torch.allclose(repaired[5, 7], ramp[5, 7])
    assert float((repaired - ramp).abs().max()) <= 3.0  # neighbours of the pair: within one step of the ramp
    assert torch.equal(repaired[~defects], ramp[~defects])


def test_median3x3_matches_a_direct_computation():
    image = torch.rand(9, 11, generator=torch.Generator().manual_seed(0))
    padded = torch.nn.functional.pad(image[None, None], (1, 1, 1, 1), mode="replicate")[0, 0]
    direct = (
        torch.stack([padded[dy : dy + 9, dx : dx + 11] for dy in range(3) for dx in range(3)], dim=-1)
        .median(dim=-1)
        .values
    )
    assert torch.allclose(median3x3(image), direct)
