"""Gradients through the conventional-LFM patterns, the lenslet-lattice projector and unrolled RL.

Tiny float64 system: 10x/0.3 air objective, 50 um square lenslets of 1 mm focal length with
the camera 1 mm behind them, 5 pixels and 3 voxels per lenslet, 3 x 3 lenslets, two depths.
The lenslet focal length and the MLA-camera distance enter the lenslet Fresnel transform,
the NA the native-image-plane Debye field; they are given in mm and plain numbers so that
gradcheck's finite-difference step (1e-6) is well scaled.
"""

from __future__ import annotations

import torch

from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.reconstruct.unrolled import richardson_lucy_unrolled
from lfm_studio.engine.systems.conventional_patterns import conventional_patterns
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem
from lfm_studio.engine.units import mm, nm, um

F64 = torch.float64
DEPTHS = (0.0, 6 * um)
LENSLETS = (3, 3)
Q = 5
PATTERN_SCALE = 1e-2  # patterns carry ~3e-3 of the emitted power per depth


def _system(na) -> ConventionalLFMSystem:
    return ConventionalLFMSystem(
        ObjectiveLens(10.0, na, 1.0, 200 * mm), 50 * um, 1 * mm, "square", 1 * mm, LENSLETS, Q, 3, 525 * nm
    )


def _projector(f_mm: torch.Tensor, d_mm: torch.Tensor, na: torch.Tensor) -> LensletLatticeProjector:
    system = _system(na)
    reach = max(system.support(abs(z)) for z in DEPTHS)
    patterns = conventional_patterns(
        system, DEPTHS, reach=reach, dtype=F64, lenslet_focal_length=f_mm * mm, mla_to_camera=d_mm * mm
    )
    return LensletLatticeProjector([([0, 1], patterns / PATTERN_SCALE)], len(DEPTHS), LENSLETS, Q)


def _nominal() -> tuple[torch.Tensor, ...]:
    return tuple(torch.tensor(v, dtype=F64, requires_grad=True) for v in (1.0, 1.0, 0.3))


def test_tensor_overrides_at_the_system_values_reproduce_the_float_patterns():
    system = _system(0.3)
    reach = system.support(max(abs(z) for z in DEPTHS))
    plain = conventional_patterns(system, DEPTHS, reach=reach, dtype=F64)
    with torch.no_grad():
        f, d, _ = _nominal()
        overridden = conventional_patterns(
            system, DEPTHS, reach=reach, dtype=F64, lenslet_focal_length=f * mm, mla_to_camera=d * mm
        )
    assert float((overridden - plain).abs().max() / plain.abs().max()) < 1e-12


def test_gradcheck_patterns_projector_unrolled_rl_loss():
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        nominal = _projector(*_nominal())
    truth = torch.rand(nominal.volume_shape, generator=gen, dtype=F64) + 0.5
    image = nominal.forward(truth).detach()
    weights = torch.rand(nominal.volume_shape, generator=gen, dtype=F64)

    def loss(f_mm, d_mm, na):
        projector = _projector(f_mm, d_mm, na)
        return (weights * richardson_lucy_unrolled(projector, image, 3)).sum()

    inputs = _nominal()
    loss(*inputs).backward()
    for value in inputs:
        assert value.grad is not None and float(value.grad) != 0.0
    assert torch.autograd.gradcheck(loss, _nominal(), eps=1e-6, atol=1e-6, rtol=1e-4)
