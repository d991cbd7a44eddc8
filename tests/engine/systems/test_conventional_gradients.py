"""Gradients through the conventional-LFM patterns, the lenslet-lattice projector and unrolled RL.

Tiny float64 system: 10x/0.3 air objective, 50 um pitch lenslets (40 um square or round clear
aperture) of 1 mm focal length with the camera 1 mm behind them, 5 pixels and 3 voxels per
lenslet, 3 x 3 lenslets, two depths. The lenslet focal length and the MLA-camera distance
enter the lenslet Fresnel transform, the NA the native-image-plane Debye field, the
wavelength both, the clear aperture the antialiased aperture coverage of the NIP samples;
they are given in mm, um and plain numbers so that gradcheck's finite-difference step (1e-6)
is well scaled. The sampling is planned from the system's floats (the grid from the pitch);
the tensors enter the physics.
"""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.operators.lenslet_lattice import LensletLatticeProjector
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.reconstruct.unrolled import richardson_lucy_unrolled
from lfm_studio.engine.systems.conventional_patterns import (
    conventional_patterns,
    nip_field_size,
    samples_per_pitch,
    sub_samples,
)
from lfm_studio.engine.systems.conventional_system import ConventionalLFMSystem
from lfm_studio.engine.units import mm, nm, um

F64 = torch.float64
DEPTHS = (0.0, 6 * um)
LENSLETS = (3, 3)
Q = 5
PATTERN_SCALE = 1e-2  # patterns carry ~3e-3 of the emitted power per depth
WAVELENGTH = 525 * nm
APERTURE = 40 * um
# f (mm), d (mm), NA, wavelength (um), clear aperture (um)
NOMINAL = (1.0, 1.0, 0.3, WAVELENGTH / um, APERTURE / um)


def _system(
    na, wavelength: float = WAVELENGTH, shape: str = "square", aperture: float = APERTURE
) -> ConventionalLFMSystem:
    return ConventionalLFMSystem(
        ObjectiveLens(10.0, na, 1.0, 200 * mm), 50 * um, 1 * mm, shape, 1 * mm, LENSLETS, Q, 3, wavelength,
        lenslet_aperture=aperture,
    )  # fmt: skip


def _reach(system: ConventionalLFMSystem) -> int:
    return max(system.support(abs(z)) for z in DEPTHS)


def _plan(system: ConventionalLFMSystem) -> tuple[int, ...]:
    """The discrete choices of a pattern build: reach, NIP samples per pitch, sensor samples per
    pixel and NIP field size."""
    reach = _reach(system)
    return reach, samples_per_pitch(system), sub_samples(system), nip_field_size(system, reach)


def _lattice(patterns: torch.Tensor) -> LensletLatticeProjector:
    return LensletLatticeProjector([([0, 1], patterns / PATTERN_SCALE)], len(DEPTHS), LENSLETS, Q)


def _projector(
    f_mm: torch.Tensor,
    d_mm: torch.Tensor,
    na: torch.Tensor,
    lam_um: torch.Tensor,
    a_um: torch.Tensor,
    shape: str = "square",
) -> LensletLatticeProjector:
    system = _system(na, shape=shape)
    patterns = conventional_patterns(
        system, DEPTHS, reach=_reach(system), dtype=F64, lenslet_focal_length=f_mm * mm,
        mla_to_camera=d_mm * mm, wavelength=lam_um * um, lenslet_aperture=a_um * um,
    )  # fmt: skip
    return _lattice(patterns)


def _nominal() -> tuple[torch.Tensor, ...]:
    return tuple(torch.tensor(v, dtype=F64, requires_grad=True) for v in NOMINAL)


def _loss_data(shape: str = "square") -> tuple[torch.Tensor, torch.Tensor]:
    """A measured image (of a random volume, at the nominal values) and the loss weights."""
    gen = torch.Generator().manual_seed(0)
    with torch.no_grad():
        nominal = _projector(*_nominal(), shape=shape)
    truth = torch.rand(nominal.volume_shape, generator=gen, dtype=F64) + 0.5
    image = nominal.forward(truth).detach()
    return image, torch.rand(nominal.volume_shape, generator=gen, dtype=F64)


def _rl_loss(projector: LensletLatticeProjector, image: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    return (weights * richardson_lucy_unrolled(projector, image, 3)).sum()


@pytest.mark.parametrize("shape", ["square", "circle"])
def test_tensor_overrides_at_the_system_values_reproduce_the_float_patterns(shape):
    system = _system(0.3, shape=shape)
    reach = system.support(max(abs(z) for z in DEPTHS))
    plain = conventional_patterns(system, DEPTHS, reach=reach, dtype=F64)
    with torch.no_grad():
        f, d, _, lam, a = _nominal()
        overridden = conventional_patterns(
            system, DEPTHS, reach=reach, dtype=F64, lenslet_focal_length=f * mm, mla_to_camera=d * mm,
            wavelength=lam * um, lenslet_aperture=a * um,
        )  # fmt: skip
    assert float((overridden - plain).abs().max() / plain.abs().max()) < 1e-12


@pytest.mark.parametrize("shape", ["square", "circle"])
def test_gradcheck_patterns_projector_unrolled_rl_loss(shape):
    image, weights = _loss_data(shape)

    def loss(f_mm, d_mm, na, lam_um, a_um):
        return _rl_loss(_projector(f_mm, d_mm, na, lam_um, a_um, shape), image, weights)

    inputs = _nominal()
    loss(*inputs).backward()
    for value in inputs:
        assert value.grad is not None and float(value.grad) != 0.0
    assert torch.autograd.gradcheck(loss, _nominal(), eps=1e-6, atol=1e-6, rtol=1e-4)


@pytest.mark.parametrize(
    ("name", "index", "value"), [("wavelength", 3, WAVELENGTH), ("aperture", 4, APERTURE)]
)
def test_gradient_matches_a_central_difference_of_the_float_path(name, index, value):
    """dLoss/dx of the tensor path against (L(x + h) - L(x - h)) / 2h, where L is the plain float
    path (no overrides, the system holding x +- h) planned at x +- h: the plans must not change.

    Wavelength: the difference error is ~3e-9 relative (it scales as h^2). Aperture: the
    antialiased coverage is piecewise linear in it, exact away from a kink.
    """
    image, weights = _loss_data()
    inputs = _nominal()
    _rl_loss(_projector(*inputs), image, weights).backward()
    gradient = float(inputs[index].grad) / um  # per metre

    h = 1e-5 * value
    plans, losses = [], []
    for x in (value - h, value + h):
        system = _system(0.3, **{name: x})
        plans.append(_plan(system))
        with torch.no_grad():
            patterns = conventional_patterns(system, DEPTHS, reach=_reach(system), dtype=F64)
            losses.append(float(_rl_loss(_lattice(patterns), image, weights)))
    assert plans == [_plan(_system(0.3))] * 2
    difference = (losses[1] - losses[0]) / (2 * h)
    assert gradient != 0.0
    assert abs(difference - gradient) <= 1e-7 * abs(gradient), (difference, gradient)
