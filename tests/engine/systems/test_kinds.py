"""System kinds (issue 13): one object per kind, dispatch, typed conventional patterns.

References are independent of the code under test: the conventional projector against a
brute-force placement of each voxel's pattern (the lattice model written out voxel by
voxel), the Fourier projector against "a point on the axis images as the PSF",
adjointness ``<A x, y> = <x, A^T y>``, and a TIFF round trip of the typed pattern layout.
"""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
import torch

from lfm_studio.engine.design import LensletSpec, MLASpec, load_preset
from lfm_studio.engine.io import read_psf_stack, write_psf_stack
from lfm_studio.engine.io.metadata import HeaderError, layout_metadata, split_layout_metadata
from lfm_studio.engine.performance.closed_forms import CLOSED_FORMS, closed_form_metrics
from lfm_studio.engine.performance.conventional_closed_forms import conventional_closed_forms
from lfm_studio.engine.performance.fourier_closed_forms import fourier_closed_forms
from lfm_studio.engine.psf_stack import ConventionalPatterns, PSFStack
from lfm_studio.engine.simulation import imaging_setup, simulate_psf
from lfm_studio.engine.systems.fourier_psf import FourierPSFReport
from lfm_studio.engine.systems.kinds import (
    CONVENTIONAL,
    FOURIER,
    KIND_NAMES,
    KINDS,
    kind_named,
    kind_of,
    stack_kind,
)
from lfm_studio.engine.systems.lenslet_cache import LensletCache

FOURIER_PRESET = "flfm_guo2019"
CONVENTIONAL_PRESET = "lfm_10x_na03"


def _preview(name: str):
    design = load_preset(name)
    return design.updated(accuracy={**design.accuracy.model_dump(), "preset": "preview"})


@pytest.fixture(scope="module")
def conventional_stack() -> PSFStack:
    # Two depths of different reach (0 and 30 um), a 60-pixel crop: a few lenslets, float64.
    return simulate_psf(_preview(CONVENTIONAL_PRESET), depths=(0.0, 30e-6), crop=60, dtype="float64")


@pytest.fixture(scope="module")
def fourier_stack() -> PSFStack:
    return simulate_psf(_preview(FOURIER_PRESET), depths=(-10e-6, 0.0), crop=96, dtype="float64")


# ----- the kind objects and dispatch -----


def test_kind_of_maps_each_design_word_to_its_object():
    assert kind_of(load_preset(FOURIER_PRESET)) is FOURIER
    assert kind_of(load_preset(CONVENTIONAL_PRESET)) is CONVENTIONAL
    assert tuple(kind.name for kind in KINDS) == KIND_NAMES and len(set(KIND_NAMES)) == len(KINDS)
    for kind in KINDS:
        assert kind_named(kind.name) is kind and kind.name in repr(kind)


@pytest.mark.parametrize("word", ["Fourier", "lightsheet", "", None, 3])
def test_an_unknown_kind_word_is_refused_naming_the_value_and_the_choices(word):
    with pytest.raises(ValueError, match=r"system kind must be one of 'fourier', 'conventional'") as caught:
        kind_named(word)
    assert repr(word) in str(caught.value)


def test_kind_of_refuses_an_object_without_a_kind():
    with pytest.raises(ValueError, match="needs a design with a 'kind'"):
        kind_of(object())


def test_capability_flags_differ_where_the_systems_do():
    assert FOURIER.shift_invariant and not CONVENTIONAL.shift_invariant
    assert FOURIER.lenslet_cache and not CONVENTIONAL.lenslet_cache
    assert FOURIER.binnable_sensor and not CONVENTIONAL.binnable_sensor
    assert FOURIER.pattern_axes == () and len(CONVENTIONAL.pattern_axes) == 2
    assert FOURIER.label != CONVENTIONAL.label


def test_simulate_psf_dispatches_to_the_design_kind(conventional_stack, fourier_stack):
    assert fourier_stack.patterns is None and fourier_stack.data.ndim == 3
    assert stack_kind(fourier_stack) is FOURIER and fourier_stack.shift_invariant
    layout = conventional_stack.patterns
    assert isinstance(layout, ConventionalPatterns) and stack_kind(conventional_stack) is CONVENTIONAL
    s = layout.voxels_per_lenslet
    assert conventional_stack.data.shape[:3] == (s, s, 2) and len(layout.reach) == 2
    assert layout.reach[1] > layout.reach[0]  # the defocused depth reaches more lenslets
    assert "kind" not in conventional_stack.metadata  # the layout is typed, not in the free-form dict


def test_closed_forms_follow_the_kind_object():
    fourier, conventional = load_preset(FOURIER_PRESET), load_preset(CONVENTIONAL_PRESET)
    assert closed_form_metrics(fourier) == fourier_closed_forms(fourier)
    assert closed_form_metrics(conventional) == conventional_closed_forms(conventional)
    with pytest.raises(ValueError, match="conventional-LFM design; got a Fourier LFM"):
        conventional_closed_forms(fourier)
    with pytest.raises(ValueError, match="Fourier-LFM design; got a Conventional LFM"):
        fourier_closed_forms(conventional)


def test_each_kind_owns_its_closed_forms():
    """``SystemKind.closed_forms`` is the kind's formula (CLOSED_FORMS agrees), with the criterion passed on."""
    fourier, conventional = load_preset(FOURIER_PRESET), load_preset(CONVENTIONAL_PRESET)
    for kind, design in ((FOURIER, fourier), (CONVENTIONAL, conventional)):
        assert kind_of(design) is kind and CLOSED_FORMS[kind] is kind.closed_forms_formula()
        assert kind.closed_forms(design) == closed_form_metrics(design) == CLOSED_FORMS[kind](design)
        abbe = kind.closed_forms(design, criterion="abbe")
        assert abbe == CLOSED_FORMS[kind](design, criterion="abbe") and abbe.lateral_criterion == "abbe"
    with pytest.raises(ValueError, match="Fourier-LFM design; got a Conventional LFM"):
        FOURIER.closed_forms(conventional)
    with pytest.raises(ValueError, match="criterion must be one of"):
        CONVENTIONAL.closed_forms(conventional, criterion="nyquist")


def _separated_lenslets_design():
    """The FLFM preset's optics with 4 separated 800 um lenslets on 256^2 px: the per-lenslet path."""
    base = _preview(FOURIER_PRESET)
    lenslets = [
        LensletSpec(center_um=(x, y), aperture_diameter_um=800.0, focal_length_mm=16.8)
        for y in (-600.0, 600.0)
        for x in (-600.0, 600.0)
    ]
    return base.updated(
        camera={**base.camera.model_dump(), "pixel_count": (256, 256)},
        relay={"focal_length_mm": 75.0, "field_stop_diameter_mm": 2.0},
        mla=MLASpec(lenslets=tuple(lenslets)),
    )


def test_the_studio_psf_route_uses_the_cache_only_for_kinds_that_have_one():
    # A Fourier design through simulate_psf with a cache: the second run takes every lenslet from it.
    design = _separated_lenslets_design()
    cache, first, second = LensletCache(), FourierPSFReport(), FourierPSFReport()
    a = simulate_psf(design, depths=(0.0,), cache=cache, report=first)
    b = simulate_psf(design, depths=(0.0,), cache=cache, report=second)
    assert (
        first.method == "per_lenslet"
        and first.lenslets_computed == [0, 1, 2, 3]
        and not first.lenslets_cached
    )
    assert second.lenslets_cached == first.lenslets_computed and not second.lenslets_computed
    assert torch.equal(a.data, b.data)
    # A conventional design ignores the cache and says which method ran.
    report, cache = FourierPSFReport(), LensletCache()
    simulate_psf(_preview(CONVENTIONAL_PRESET), depths=(0.0,), crop=30, cache=cache, report=report)
    assert report.method == "conventional" and cache.misses == 0 and len(cache) == 0


# ----- projectors against independent references -----


def _brute_force_conventional(stack: PSFStack, volume: torch.Tensor) -> torch.Tensor:
    """The lattice model voxel by voxel: the volume rotated 180 degrees; voxel ``S j + p`` at depth ``z``
    adds pattern ``[p, z]`` (its ``(2 R + 3) Q`` centre) centred on lenslet ``j``, cut at the sensor edge."""
    layout = stack.patterns
    q, s = layout.pixels_per_lenslet, layout.voxels_per_lenslet
    ly, lx = layout.lenslets
    image = torch.zeros((ly * q, lx * q), dtype=torch.float64)
    flipped = volume.flip(-2, -1).double()
    width = stack.data.shape[-1]
    for z in range(len(stack.depths)):
        h = layout.width(z)
        start = (width - h) // 2
        half = (h // q) // 2
        for a, b in torch.nonzero(flipped[z]).tolist():
            (jy, py), (jx, px) = divmod(a, s), divmod(b, s)
            pattern = stack.data[py, px, z, start : start + h, start : start + h].double()
            y0, x0 = (jy - half) * q, (jx - half) * q
            ys, xs = max(0, y0), max(0, x0)
            ye, xe = min(ly * q, y0 + h), min(lx * q, x0 + h)
            image[ys:ye, xs:xe] += flipped[z, a, b] * pattern[ys - y0 : ye - y0, xs - x0 : xe - x0]
    return image


def test_conventional_projector_matches_the_voxel_by_voxel_lattice_model(conventional_stack):
    setup = imaging_setup(conventional_stack)
    layout = conventional_stack.patterns
    assert setup.volume_shape == (
        2,
        layout.lenslets[0] * layout.voxels_per_lenslet,
        layout.lenslets[1] * layout.voxels_per_lenslet,
    )
    generator = torch.Generator().manual_seed(0)
    volume = torch.rand(setup.volume_shape, generator=generator, dtype=torch.float64)
    volume[volume < 0.7] = 0.0  # sparse: a few dozen voxels, some next to the edges
    expected = _brute_force_conventional(conventional_stack, volume)
    got = setup.projector.forward(volume).double()
    assert float(expected.norm()) > 0
    assert float((got - expected).norm() / expected.norm()) < 1e-10
    # Lateral voxel P / (M S) from the design, independent of the engine's formula.
    design = conventional_stack.design
    pitch = design.mla.pitch_um * 1e-6
    assert setup.voxel_size[1] == pytest.approx(pitch / (design.magnification * layout.voxels_per_lenslet))
    assert setup.voxel_size[0] == pytest.approx(30e-6)


@pytest.mark.parametrize("which", ["conventional", "fourier"])
def test_each_kind_projector_is_adjoint_to_its_back_projection(which, conventional_stack, fourier_stack):
    stack = conventional_stack if which == "conventional" else fourier_stack
    projector = imaging_setup(stack).projector
    generator = torch.Generator().manual_seed(1)
    x = torch.rand(projector.volume_shape, generator=generator, dtype=torch.float64)
    y = torch.rand(projector.image_shape, generator=generator, dtype=torch.float64)
    lhs = float((projector.forward(x).double() * y).sum())
    rhs = float((x * projector.adjoint(y).double()).sum())
    assert lhs == pytest.approx(rhs, rel=1e-9)


def test_fourier_projector_images_an_axial_point_as_the_psf(fourier_stack):
    setup = imaging_setup(fourier_stack)
    z, ny, nx = setup.volume_shape
    assert ny % 2 == 1 and nx % 2 == 1  # a voxel on the optical axis
    assert setup.voxel_size[1] == pytest.approx(fourier_stack.object_pixel_size, rel=1e-12)
    for depth in range(z):
        point = torch.zeros(setup.volume_shape, dtype=torch.float64)
        point[depth, ny // 2, nx // 2] = 1.0
        image = setup.projector.forward(point).double()
        psf = fourier_stack.data[depth].double()
        assert float((image - psf).norm() / psf.norm()) < 1e-9


def test_a_fixed_lateral_count_keeps_the_grid_and_the_default_is_the_odd_field_of_view_count(fourier_stack):
    """``shift_invariant_setup(lateral=n)`` (the end-to-end optimiser's fixed grid) differs from the
    default only in the lateral count; the default is :func:`shift_invariant_lateral`."""
    from lfm_studio.engine.systems.kinds_fourier import shift_invariant_lateral, shift_invariant_setup

    default = imaging_setup(fourier_stack)
    count = shift_invariant_lateral(fourier_stack)
    assert count % 2 == 1 and default.volume_shape == (2, count, count)
    same = shift_invariant_setup(fourier_stack, lateral=count)
    assert same.volume_shape == default.volume_shape and same.voxel_size == default.voxel_size
    point = torch.zeros(default.volume_shape, dtype=torch.float64)
    point[1, count // 2, count // 2] = 1.0
    assert torch.equal(same.projector.forward(point), default.projector.forward(point))
    fixed = shift_invariant_setup(fourier_stack, lateral=7)
    assert fixed.volume_shape == (2, 7, 7) and fixed.voxel_size == default.voxel_size
    assert fixed.projector.image_shape == default.projector.image_shape
    assert shift_invariant_lateral(fourier_stack, field_of_view=10.5 * fourier_stack.object_pixel_size) == 11


# ----- the typed pattern stack -----


def test_pattern_layout_round_trips_through_the_psf_tiff(conventional_stack, tmp_path):
    path = write_psf_stack(tmp_path / "patterns.tif", conventional_stack)
    back = read_psf_stack(path, dtype=torch.float64)
    assert back.patterns == conventional_stack.patterns and back.metadata == conventional_stack.metadata
    assert back.data.shape == conventional_stack.data.shape
    volume = torch.rand(imaging_setup(back).volume_shape, generator=torch.Generator().manual_seed(2))
    a = imaging_setup(conventional_stack).projector.forward(volume.double())
    b = imaging_setup(back).projector.forward(volume.double())
    assert float((a - b).norm() / a.norm()) < 1e-6  # (the TIFF keeps the data's float32/64 values)
    # A shift-invariant stack stays one: no pattern layout is invented on reading.
    slices = replace(conventional_stack, data=conventional_stack.data[0, 0], patterns=None)
    plain = read_psf_stack(write_psf_stack(tmp_path / "plain.tif", slices))
    assert plain.patterns is None and plain.shift_invariant


def test_the_file_layout_of_a_pattern_stack_is_the_documented_metadata_entries():
    layout = ConventionalPatterns(pixels_per_lenslet=5, voxels_per_lenslet=3, reach=(1, 2), lenslets=(4, 6))
    entries = layout_metadata(layout)
    assert json.loads(json.dumps(entries)) == {
        "kind": "conventional",
        "pixels_per_lenslet": 5,
        "voxels_per_lenslet": 3,
        "reach": [1, 2],
        "lenslets": [4, 6],
    }
    parsed, rest = split_layout_metadata({**entries, "note": "kept"})
    assert parsed == {"patterns": layout} and rest == {"note": "kept"}
    assert split_layout_metadata({"method": "per_lenslet"}) == ({}, {"method": "per_lenslet"})
    assert layout_metadata(None) == {} and layout_metadata(None, 1) == {}
    assert layout_metadata(None, 3) == {"volume_oversampling": 3}
    assert split_layout_metadata({"volume_oversampling": 3}) == ({"volume_oversampling": 3}, {})


def test_each_kind_knows_its_image_shape_before_computing_the_psf(conventional_stack, fourier_stack):
    # What a video checks its frames against before the (long) PSF simulation.
    conventional, fourier = _preview(CONVENTIONAL_PRESET), _preview(FOURIER_PRESET)
    assert (
        CONVENTIONAL.image_shape(conventional, crop=60)
        == imaging_setup(conventional_stack).projector.image_shape
    )
    assert (
        FOURIER.image_shape(fourier, crop=96)
        == imaging_setup(fourier_stack).projector.image_shape
        == (96, 96)
    )
    assert FOURIER.image_shape(fourier) == fourier.camera.pixel_count
    layout = conventional_stack.patterns
    assert CONVENTIONAL.image_shape(conventional, crop=60) == tuple(
        n * layout.pixels_per_lenslet for n in layout.lenslets
    )


def test_an_oversampled_fourier_stack_keeps_its_binning_through_the_tiff(tmp_path):
    # A stack sampled 3 x finer than the camera: the projector bins 3 x 3 before and after a round trip.
    base = _preview(FOURIER_PRESET)
    design = base.updated(accuracy={**base.accuracy.model_dump(), "volume_oversampling": 3})
    stack = simulate_psf(design, depths=(0.0,), crop=32)
    assert stack.volume_oversampling == 3 and stack.data.shape[-2:] == (3 * 32 + 2, 3 * 32 + 2)
    back = read_psf_stack(write_psf_stack(tmp_path / "fine.tif", stack))
    assert back.volume_oversampling == 3 and back.metadata == stack.metadata
    for each in (stack, back):
        assert imaging_setup(each).projector.image_shape == (32, 32) == FOURIER.image_shape(design, crop=32)
    with pytest.raises(ValueError, match="volume_oversampling must be an odd integer"):
        replace(stack, volume_oversampling=2)


@pytest.mark.parametrize(
    ("entries", "message"),
    [
        ({"kind": "conventional", "pixels_per_lenslet": 5, "voxels_per_lenslet": 3, "lenslets": [2, 2]}, "reach"),
        (
            {"kind": "conventional", "pixels_per_lenslet": 4, "voxels_per_lenslet": 3, "reach": [1], "lenslets": [2, 2]},
            "pixels_per_lenslet must be an odd integer",
        ),
        (
            {"kind": "conventional", "pixels_per_lenslet": 5, "voxels_per_lenslet": 3, "reach": [-1], "lenslets": [2, 2]},
            "reach must list one integer >= 0",
        ),
    ],
)  # fmt: skip
def test_a_malformed_pattern_layout_is_a_header_error_naming_the_field(entries, message):
    with pytest.raises(HeaderError, match=message):
        split_layout_metadata(entries, where="file.tif")


def test_pattern_layout_must_match_the_data(conventional_stack):
    layout = conventional_stack.patterns
    with pytest.raises(ValueError, match=r"shape \(S, S, Z, H, H\)"):
        replace(conventional_stack, patterns=replace(layout, reach=(*layout.reach, 0)))
    with pytest.raises(ValueError, match=r"shape \(S, S, Z, H, H\)"):
        conventional_stack.with_data(conventional_stack.data[0])
    with pytest.raises(TypeError, match="ConventionalPatterns or None"):
        replace(conventional_stack, patterns={"reach": list(layout.reach)})


# ----- devices -----


def test_a_conventional_projector_reports_its_real_device(conventional_stack):
    # The studio moves the frame to ``projector.device`` (it used to assume cpu for a conventional one).
    meta = conventional_stack.to("meta")
    projector = imaging_setup(meta).projector
    assert projector.device == torch.device("meta") and projector.dtype == torch.float64
    assert imaging_setup(conventional_stack).projector.device == torch.device("cpu")
