"""Each accuracy preset meets its stated error bound on every shipped design.

Bound: ``PRESET_ERROR_BOUNDS[kind][preset]``, the worst-depth relative L2 error of the
preset's PSF stack against a converged reference (:mod:`lfm_studio.bench.metrics`).
What is computed (the same cases as ``lfm-studio bench``, docs/benchmarks.md):

- XLFM (per-lenslet path): the innermost and outermost lenslet of each focal length; the
  windows do not overlap, so the worst lenslet's error bounds the whole array's.
- Guo FLFM (sub-images overlap: full-field reference; preview and standard take the coherent
  per-lenslet path, reference the full field): a centred 512 x 512 sensor crop that holds the
  whole array's footprint.
- conventional designs: every voxel sub-position's pattern.

Depths: the bench's three (both ends of the design's range and the focal plane); the error
is the worst of them.
The reference is :func:`lfm_studio.bench.knobs.reference_plan` (Fourier: float64 with the
exact pixel integration; conventional: the Richardson extrapolation of two samplings).
"""

from __future__ import annotations

import dataclasses

import pytest

from lfm_studio.bench.cases import bench_case
from lfm_studio.bench.compute import compute_stack, depth_first, reference_stack
from lfm_studio.bench.knobs import preset_options, reference_plan
from lfm_studio.bench.metrics import psf_error
from lfm_studio.engine.design import ACCURACY_PRESETS, list_presets, load_preset
from lfm_studio.engine.design.accuracy import PRESET_ERROR_BOUNDS

SHIPPED = ("flfm_guo2019", "lfm_10x_na03", "lfm_prevedel2014", "xlfm_cong2017")


def test_every_shipped_design_is_covered():
    assert set(SHIPPED) == set(list_presets())


@pytest.mark.slow
@pytest.mark.parametrize("name", SHIPPED)
def test_each_preset_meets_its_bound(name):
    case = bench_case(load_preset(name), name)
    assert len(case.depths) == 3
    reference = depth_first(reference_stack(case, reference_plan(case)))
    errors = {}
    for preset in ACCURACY_PRESETS:
        stack, warned = compute_stack(case, preset_options(case, preset))
        assert not warned, (preset, warned)
        errors[preset] = psf_error(depth_first(stack), reference)
    bounds = PRESET_ERROR_BOUNDS[case.kind]
    assert all(errors[p] <= bounds[p] for p in ACCURACY_PRESETS), (errors, bounds)
    # The presets are ordered: none is less accurate than the one before (XLFM: all three are
    # limited by the same lenslet window margin, 2.1e-4, once the pixel integral is exact).
    assert errors["reference"] <= errors["standard"] + 1e-6 <= errors["preview"] + 2e-6, errors


def test_paraxial_debye_on_axis_matches_its_closed_form():
    # Paraxial model: uniform pupil amplitude (P = cos theta) and phase -n k z sin^2(theta) / 2,
    # so U(0, z) / U(0, 0) = (1 - exp(-j a s^2)) / (j a s^2) with a = n k z / 2, s = NA / n.
    import math

    import torch

    from lfm_studio.engine.optics.debye import debye_integral
    from lfm_studio.engine.optics.objective import ObjectiveLens

    objective = ObjectiveLens(20, 0.5, 1.333, 0.18)
    wavelength = 525e-9
    z = torch.tensor([0.0, 2e-6, 7e-6, -15e-6], dtype=torch.float64)
    field = debye_integral(objective, wavelength, torch.zeros(1, dtype=torch.float64), z, model="paraxial")[
        :, 0
    ]
    a = 1.333 * 2 * math.pi / wavelength * z / 2
    x = a * (0.5 / 1.333) ** 2
    expected = torch.where(
        x == 0, torch.ones_like(x), torch.sin(x / 2) / (x / 2).where(x != 0, torch.ones_like(x))
    )
    ratio = (field / field[0]).abs()
    assert torch.allclose(ratio, expected.abs(), rtol=0, atol=1e-12), (ratio, expected)
    debye = debye_integral(objective, wavelength, torch.zeros(1, dtype=torch.float64), z)[:, 0]
    assert float((debye / debye[0]).abs()[2] - ratio[2]).__abs__() > 1e-3  # the models differ at NA 0.5


def test_fourier_padding_reaches_the_full_field_and_fresnel_ir_is_refused():
    from lfm_studio.engine.systems.fourier_psf import FourierAccuracy, fourier_psf_stack
    from lfm_studio.engine.systems.from_design import fourier_accuracy_of, fourier_system_of

    design = load_preset("flfm_guo2019")
    assert fourier_accuracy_of(design.updated(accuracy={"preset": "standard", "padding": 1.5})).padding == 1.5
    small = design.updated(camera={**design.camera.model_dump(), "pixel_count": (384, 384)})
    system = fourier_system_of(small)
    base = FourierAccuracy(oversampling=1, method="full_field", propagator="bandlimited_asm")
    padded = fourier_psf_stack(system, (40e-6,), accuracy=base).data
    unpadded = fourier_psf_stack(system, (40e-6,), accuracy=dataclasses.replace(base, padding=1.0)).data
    change = float((padded - unpadded).norm() / padded.norm())
    assert 1e-6 < change < 0.05, change  # wrap-around of the tails: small but not nothing
    with pytest.raises(ValueError, match="propagator 'fresnel_ir' cannot feed the full-field"):
        fourier_psf_stack(system, (0.0,), accuracy=dataclasses.replace(base, propagator="fresnel_ir"))


def test_conventional_knobs_reach_the_patterns():
    import torch

    from lfm_studio.engine.errors import SamplingWarning
    from lfm_studio.engine.systems.conventional_patterns import sub_samples
    from lfm_studio.engine.systems.conventional_psf import ConventionalAccuracy, conventional_psf_stack
    from lfm_studio.engine.systems.from_design import conventional_accuracy_of, conventional_system_of

    design = load_preset("lfm_10x_na03")
    acc = conventional_accuracy_of(design.updated(accuracy={"preset": "preview", "dtype": "float64"}))
    assert (acc.dtype, acc.model) == (torch.float64, "debye")
    assert (
        sub_samples(conventional_system_of(design), acc.pixel_oversampling) == 3
    )  # 2 ** 1 + 1 (preview: oversampling 1)
    system = conventional_system_of(design, lenslets=(3, 3), pixels_per_lenslet=5, voxels_per_lenslet=3)
    depths = (10e-6,)
    base = ConventionalAccuracy(dtype=torch.float64)
    ref = conventional_psf_stack(system, depths, accuracy=base).data
    changes = (
        dict(model="paraxial"),
        dict(pixel_oversampling=2.8),
        dict(nip_oversampling=1.5),
        dict(pixel_integration="fourier"),
    )
    for change in changes:
        other = conventional_psf_stack(system, depths, accuracy=dataclasses.replace(base, **change)).data
        assert float((other - ref).norm() / ref.norm()) > 1e-4, change
    with pytest.warns(SamplingWarning, match="n_quadrature = 16"):
        conventional_psf_stack(system, depths, accuracy=dataclasses.replace(base, debye_points=16))
    pair = (10e-6, 0.0)
    whole = conventional_psf_stack(system, pair, accuracy=base).data
    chunked = conventional_psf_stack(system, pair, accuracy=dataclasses.replace(base, depth_chunk=1)).data
    # Chunks only batch the Debye NIP fields; every depth is transformed alone either way.
    assert float((chunked - whole).norm() / whole.norm()) < 1e-12


def test_conventional_presets_take_the_exact_pixel_integral_at_fewer_sub_samples():
    from lfm_studio.engine.systems.conventional_patterns import sub_samples
    from lfm_studio.engine.systems.from_design import conventional_accuracy_of, conventional_system_of

    for name in ("lfm_10x_na03", "lfm_prevedel2014"):
        design = load_preset(name)
        system = conventional_system_of(design)
        for integration, counts in (("fourier", (3, 3, 5)), ("midpoint", (3, 5, 9))):
            for preset, count in zip(ACCURACY_PRESETS, counts, strict=True):
                spec = design.updated(accuracy={"preset": preset, "pixel_integration": integration})
                acc = conventional_accuracy_of(spec)
                assert acc.pixel_integration == integration
                assert sub_samples(system, acc.pixel_oversampling) == count, (name, integration, preset)
    assert {knobs["pixel_integration"] for knobs in ACCURACY_PRESETS.values()} == {"fourier"}


def test_preset_descriptions_state_the_knobs_and_the_tested_bounds():
    from lfm_studio.engine.design import describe_preset

    for name, knobs in ACCURACY_PRESETS.items():
        text = describe_preset(name)
        assert text.startswith(f"{name}: oversampling {knobs['oversampling']}, {knobs['dtype']}")
        for kind, label in (("fourier", "Fourier"), ("conventional", "conventional")):
            assert f"{100 * PRESET_ERROR_BOUNDS[kind][name]:g} % ({label} LFM)" in text
