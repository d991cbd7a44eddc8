"""A Zernike phase on the relayed pupil of a Fourier LFM (``FourierLFMSystem.pupil_zernike_waves``,
a design's ``pupil_phase``): zero terms change nothing, defocus equals a depth shift, tilt moves
the sub-images by the closed-form amount, both PSF paths apply it alike, and the per-lenslet path
has the finite-difference gradient in a coefficient.

System as in test_fourier_gradients: 20x/0.12 water objective (f_obj = 9 mm), Fourier lens 60 mm
(m_r = 1/3: relayed pupil radius R = NA f_obj m_r = 0.36 mm), three 0.25 mm lenslets of 5 mm focal
length, camera 5 mm behind, 8 um pixels, float64.
"""

from __future__ import annotations

import dataclasses
import importlib
import math

import pytest
import torch

from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.systems import fourier_lenslet
from lfm_studio.engine.systems.fourier_parameters import FourierParameters
from lfm_studio.engine.systems.fourier_psf import FourierAccuracy, FourierPSFReport, fourier_psf_stack
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem
from lfm_studio.engine.systems.lenslet_cache import LensletCache
from lfm_studio.engine.units import mm, nm, um

F64 = torch.float64
pupil_field_module = importlib.import_module(
    "lfm_studio.engine.optics.pupil_field"
)  # (the package exports a function of that name)
N_IMM, NA, WAVELENGTH, D_CAM = 1.33, 0.12, 525 * nm, 5 * mm
CENTRES = ((0.013 * mm, -0.021 * mm), (0.3 * mm, 0.05 * mm), (-0.12 * mm, -0.28 * mm))
SYSTEM = FourierLFMSystem(
    ObjectiveLens(20.0, NA, N_IMM, 180 * mm),
    60 * mm,
    MicrolensArray(
        tuple(
            Lenslet(c, 0.25 * mm, 5 * mm, s)
            for c, s in zip(CENTRES, ("circle", "square", "circle"), strict=True)
        )
    ),
    D_CAM,
    8 * um,
    (96, 96),
    WAVELENGTH,
)
ACC = FourierAccuracy(method="per_lenslet", oversampling=2, margin_airy=8, dtype=F64)
DEPTHS = (-4 * um, 3 * um)


def _masked(terms) -> FourierLFMSystem:
    return dataclasses.replace(SYSTEM, pupil_zernike_waves=tuple(terms.items()))


def _stack(system, depths=DEPTHS, accuracy=ACC, **kwargs) -> torch.Tensor:
    return fourier_psf_stack(system, depths, accuracy=accuracy, **kwargs).data


def _relative(a: torch.Tensor, b: torch.Tensor) -> float:
    return float((a - b).norm() / b.norm())


def test_pupil_radius_is_the_relayed_pupil():
    assert SYSTEM.pupil_radius_at_mla == pytest.approx(0.36 * mm, rel=1e-12)


def test_zero_coefficients_equal_no_mask_on_both_paths():
    for method in ("per_lenslet", "full_field"):
        acc = dataclasses.replace(ACC, method=method)
        plain = _stack(SYSTEM, accuracy=acc)
        zero = _stack(_masked({4: 0.0, 7: 0.0, 11: 0.0}), accuracy=acc)
        assert torch.allclose(zero, plain, rtol=1e-12, atol=1e-15 * float(plain.max())), method


def test_defocus_term_equals_the_psf_of_a_shifted_depth():
    """Paraxial pupil: the defocus phase of depth z is -k z rho^2 / (2 n f_obj^2), rho the pupil
    height; Noll 4 of c waves is 2 pi c sqrt(3) (2 rho^2 / (NA f_obj)^2 - 1). Equal quadratic parts
    (the constant is a piston) give: mask c at depth z = no mask at depth z + dz with
    dz = -4 sqrt(3) c n lambda / NA^2 (-16.8 um for c = 0.05). Exact up to rounding, both paths."""
    c = 0.05
    dz = -4 * math.sqrt(3) * c * N_IMM * WAVELENGTH / NA**2
    assert dz == pytest.approx(-16.79 * um, rel=1e-3)
    for method in ("per_lenslet", "full_field"):
        acc = dataclasses.replace(ACC, method=method, model="paraxial")
        masked = _stack(_masked({4: c}), accuracy=acc)
        shifted = _stack(SYSTEM, depths=tuple(z + dz for z in DEPTHS), accuracy=acc)
        unshifted = _stack(SYSTEM, accuracy=acc)
        assert _relative(masked, shifted) < 1e-9, method
        assert _relative(masked, unshifted) > 0.1  # the mask does defocus


@pytest.mark.parametrize(("noll", "dim"), [(2, -1), (3, -2)])
@pytest.mark.parametrize("pixels", [2, -1])
def test_tilt_moves_every_sub_image_by_the_closed_form_amount(noll, dim, pixels):
    """Noll 2 = 2 x / R (3: 2 y / R) of c waves is the linear phase 4 pi c x / R on the MLA plane: a
    ray angle 2 c lambda / R, so every sub-image moves by 2 c lambda d / R on the sensor (+x: columns,
    +y: rows). With c chosen for a whole number of pixels (c = 1.097 waves for 2 px) the sampled
    PSF is the plain one rolled by that many pixels, up to the light that wraps at the lenslet
    windows' edges (~1e-3); one pixel more or less is off by ~100 %."""
    c = pixels * SYSTEM.pupil_radius_at_mla * SYSTEM.pixel_pitch / (2 * WAVELENGTH * D_CAM)
    plain = _stack(SYSTEM)
    tilted = _stack(_masked({noll: c}))
    assert _relative(tilted, torch.roll(plain, pixels, dims=dim)) < 2e-3
    for wrong in (pixels - 1, pixels + 1):
        assert _relative(tilted, torch.roll(plain, wrong, dims=dim)) > 0.5


def test_both_paths_form_the_mask_in_one_function_and_agree(monkeypatch):
    """The per-lenslet and full-field paths both get the mask from pupil_terms_at (one code path):
    every call receives the system's terms; and the change the mask makes agrees between the two
    paths as well as the paths themselves agree (Fresnel vs band-limited ASM, window truncation)."""
    terms = {4: 0.05, 7: 0.1, 11: -0.05}
    system = _masked(terms)
    seen = []
    original = pupil_field_module.pupil_terms_at

    def spy(*args, **kwargs):
        seen.append(dict(kwargs.get("zernike_waves") or {}))
        return original(*args, **kwargs)

    monkeypatch.setattr(pupil_field_module, "pupil_terms_at", spy)
    monkeypatch.setattr(fourier_lenslet, "pupil_terms_at", spy)
    full_acc = dataclasses.replace(ACC, method="full_field", propagator="bandlimited_asm")
    fast, full = _stack(system), _stack(system, accuracy=full_acc)
    assert seen and all(s == terms for s in seen)
    assert len(seen) == 3 + len(DEPTHS)  # one per lenslet, one per full-field depth
    fast0, full0 = _stack(SYSTEM), _stack(SYSTEM, accuracy=full_acc)
    assert _relative(fast, full) < 0.02
    change_fast, change_full = fast - fast0, full - full0
    assert _relative(change_fast, change_full) < 0.05
    assert float(change_fast.norm() / fast0.norm()) > 0.1


def test_mask_is_in_the_cache_key():
    cache = LensletCache()
    _stack(SYSTEM, cache=cache)
    report = FourierPSFReport()
    masked = _stack(_masked({8: 0.2}), cache=cache, report=report)
    assert report.lenslets_computed == [0, 1, 2] and report.lenslets_cached == []
    report = FourierPSFReport()
    again = _stack(_masked({8: 0.2}), cache=cache, report=report)
    assert report.lenslets_cached == [0, 1, 2] and torch.equal(again, masked)


def test_coefficient_gradient_equals_a_central_difference():
    weights = torch.rand(
        len(DEPTHS), *SYSTEM.sensor_shape, generator=torch.Generator().manual_seed(5), dtype=F64
    )
    system = _masked({4: 0.05, 11: -0.02})

    def loss(c4: torch.Tensor, c8: torch.Tensor) -> torch.Tensor:
        parameters = FourierParameters(zernike_waves={4: c4, 8: c8})
        return (weights * _stack(system, parameters=parameters) * 1e3).sum()

    c4 = torch.tensor(0.05, dtype=F64, requires_grad=True)
    c8 = torch.tensor(0.1, dtype=F64, requires_grad=True)  # a term the system does not list
    loss(c4, c8).backward()
    h = 1e-5
    with torch.no_grad():
        d4 = (loss(c4 + h, c8) - loss(c4 - h, c8)) / (2 * h)
        d8 = (loss(c4, c8 + h) - loss(c4, c8 - h)) / (2 * h)
    for grad, numeric in ((c4.grad, d4), (c8.grad, d8)):
        assert abs(float(numeric)) > 1e-4
        assert float(grad) == pytest.approx(float(numeric), rel=1e-6)
    assert torch.autograd.gradcheck(lambda a, b: loss(a, b), (c4.detach().requires_grad_(), c8.detach().requires_grad_()),
                                    eps=1e-6, atol=1e-6, rtol=1e-5)  # fmt: skip


def test_parameters_override_the_system_terms_and_errors_are_named():
    # A parameter equal to the system's value reproduces the plain (cached-path) stack.
    system = _masked({4: 0.05})
    plain = _stack(system)
    same = _stack(system, parameters=FourierParameters(zernike_waves={4: torch.tensor(0.05, dtype=F64)}))
    assert _relative(same, plain) < 1e-12
    other = _stack(SYSTEM, parameters=FourierParameters(zernike_waves={4: torch.tensor(0.05, dtype=F64)}))
    assert _relative(other, plain) < 1e-12
    with pytest.raises(ValueError, match=r"FourierParameters.zernike_waves\[4\] must be a real 0-d tensor"):
        _stack(SYSTEM, parameters=FourierParameters(zernike_waves={4: torch.tensor([0.1])}))
    with pytest.raises(
        ValueError, match=r"FourierParameters.zernike_waves keys must be Noll indices >= 1; got 0"
    ):
        _stack(SYSTEM, parameters=FourierParameters(zernike_waves={0: torch.tensor(0.1)}))
    with pytest.raises(ValueError, match="pupil_zernike_waves: Noll indices must be integers >= 1"):
        _masked({0: 0.1})
    with pytest.raises(ValueError, match="lists a Noll index twice"):
        dataclasses.replace(SYSTEM, pupil_zernike_waves=((4, 0.1), (4, 0.2)))
