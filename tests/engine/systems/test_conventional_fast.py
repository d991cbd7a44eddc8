"""Conventional LFM fast path: shared row transforms, skipped dark blocks and per-depth light radii
against a plain per-lenslet sum of ``T @ patch @ T.T`` windows on the sensor canvas.

Small test system as in ``test_conventional.py`` (10x/0.3, 125 um lenslets, 5 px and 3 voxels
per lenslet); float64 throughout, so the two code paths agree to round-off.
"""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.optics.phase_kernels import aperture_coverage
from lfm_studio.engine.systems.conventional_patterns import (
    conventional_patterns,
    lenslet_transform,
    light_radius,
    lit_lenslets,
    nip_fields,
    offset_pattern,
    offset_row_patterns,
    samples_per_pitch,
    sub_samples,
)
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem
from lfm_studio.engine.units import mm, nm, um

F64 = torch.float64


def _system(shape: str) -> ConventionalLFMSystem:
    return ConventionalLFMSystem(
        ObjectiveLens(10, 0.3, 1.0, 200 * mm), 125 * um, 1.875 * mm, shape, 1.875 * mm, (5, 5), 5, 3, 525 * nm
    )


def _per_lenslet_pattern(
    system: ConventionalLFMSystem, field: torch.Tensor, a: int, b: int, reach: int, lit: torch.Tensor
) -> torch.Tensor:
    """Reference: every lit lenslet's patch through ``T @ patch @ T.T`` onto its 3-pitch window, one by one."""
    ns, m, q = samples_per_pitch(system), sub_samples(system), system.pixels_per_lenslet
    step, p = ns // system.voxels_per_lenslet, q * m
    transform = lenslet_transform(system, ns, 3 * p)
    aperture = torch.ones((ns, ns), dtype=torch.complex128)
    if system.lenslet_shape == "circle":
        dx = system.pitch / ns
        y, x = Grid(ns, dx).axes()
        aperture = aperture_coverage("circle", x[None, :], y[:, None], system.pitch, (dx, dx), antialias=True)
    canvas = torch.zeros(((2 * reach + 3) * p,) * 2, dtype=torch.complex128)
    centre = field.shape[-1] // 2
    for i in range(-reach, reach + 1):
        for j in range(-reach, reach + 1):
            if not lit[reach + i, reach + j]:
                continue
            cy, cx = centre - a * step + i * ns, centre - b * step + j * ns
            patch = field[cy - ns // 2 : cy + ns // 2 + 1, cx - ns // 2 : cx + ns // 2 + 1] * aperture
            window = canvas[(reach + i) * p : (reach + i + 3) * p, (reach + j) * p : (reach + j + 3) * p]
            window += transform @ patch @ transform.T
    power = canvas.abs() ** 2 * (system.pitch / p) ** 2
    n = power.shape[-1] // m
    return power.reshape(n, m, n, m).sum(dim=(1, 3))


@pytest.mark.parametrize("shape", ["square", "circle"])
def test_row_shared_patterns_with_dark_lenslets_equal_the_per_lenslet_sum(shape):
    system = _system(shape)
    z = -80 * um
    reach = system.support(z)
    base = nip_fields(system, (z,), reach=reach, dtype=F64)
    radius = light_radius(system, (z,), margin=2.0)  # a tight radius: several lenslets dark
    bs = (-1, 0, 1)
    fast = offset_row_patterns(system, base, 1, bs, reach=reach, dtype=F64, light_radius=radius)
    for b, pattern in zip(bs, fast, strict=True):
        lit = lit_lenslets(system, reach, 1, b, radius)
        assert 0 < int(lit.sum()) < lit.numel() - 4  # the test exercises skipped blocks
        reference = _per_lenslet_pattern(system, base[0], 1, b, reach, lit)
        assert torch.allclose(pattern[0], reference, rtol=0, atol=1e-11 * float(reference.max()))


def test_each_depth_uses_its_own_light_radius():
    system = _system("square")
    depths = (-60 * um, -80 * um)
    reach = max(system.support(z) for z in depths)
    base = nip_fields(system, depths, reach=reach, dtype=F64)
    together = conventional_patterns(system, depths, reach=reach, dtype=F64, nip_field=base)
    half = system.voxels_per_lenslet // 2
    radii = [light_radius(system, (z,)) for z in depths]
    assert not torch.equal(
        lit_lenslets(system, reach, 1, 1, radii[0]), lit_lenslets(system, reach, 1, 1, radii[1])
    )
    for index, radius in enumerate(radii):
        alone = offset_pattern(
            system, base[index : index + 1], 1, 1, reach=reach, dtype=F64, light_radius=radius
        )
        assert torch.allclose(
            together[index, 1 + half, 1 + half], alone[0], rtol=0, atol=1e-12 * float(alone.max())
        )


def test_light_radius_list_must_match_the_depths():
    system = _system("square")
    base = nip_fields(system, (0.0, 10 * um), reach=1, dtype=F64)
    with pytest.raises(ValueError, match="light_radius has 1 entries for 2 depths"):
        offset_row_patterns(system, base, 0, (0,), reach=1, dtype=F64, light_radius=[1e-4])
