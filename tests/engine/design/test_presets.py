"""Bundled presets: the four published / reference designs load cleanly and resolve by name or path."""

from __future__ import annotations

import json
import warnings

import pytest

from lfm_studio.engine.design import (
    Design,
    DesignFileError,
    MLASpec,
    RegularMLASpec,
    list_presets,
    load_preset,
    resolve_design,
    save_design,
)
from lfm_studio.resources_access import resource_path

PRESETS = ["flfm_guo2019", "lfm_10x_na03", "lfm_prevedel2014", "xlfm_cong2017"]


def test_the_four_presets_are_listed():
    assert list_presets() == PRESETS


@pytest.mark.parametrize("name", PRESETS)
def test_preset_loads_and_validates_without_any_warning(name):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every warning, ours or pydantic's, fails the test
        design = load_preset(name)
    assert isinstance(design, Design)
    assert design.source and design.assumed  # cites its source and flags what was assumed


@pytest.mark.parametrize("name", PRESETS)
def test_preset_file_carries_source_and_assumed_and_is_indented(name):
    text = resource_path("designs", f"{name}.json").read_text(encoding="utf-8")
    data = json.loads(text)
    assert isinstance(data["source"], str) and len(data["source"]) > 20
    assert isinstance(data["assumed"], list) and all(isinstance(note, str) for note in data["assumed"])
    assert text.startswith('{\n  "schema_version": 1,\n')


def test_xlfm_preset_follows_cong_2017():
    design = load_preset("xlfm_cong2017")
    assert design.kind == "fourier"
    assert (design.objective.magnification, design.objective.numerical_aperture) == (20.0, 1.0)
    assert design.objective.immersion_index == pytest.approx(1.333)
    assert design.mla.count == 27 and design.mla.focal_lengths_mm == (26.0, 28.5)  # two focal groups
    # Camera midway between the two groups' focal planes (the paper's choice).
    assert design.mla_to_camera_distance_mm == pytest.approx((26.0 + 28.5) / 2, rel=1e-12)
    assert design.camera.pixel_pitch_um == 6.5 and design.camera.pixel_count == (2048, 2048)


def test_guo_preset_reproduces_the_papers_occupancy_ratio_and_field_of_view():
    design = load_preset("flfm_guo2019")
    # Guo et al. 2019, Appendix B: N = D_pupil / d_MLA = 5.9375; Appendix D: FOV = 66.96 um
    # (our field stop is 0.7 % smaller, 66.5 um, to keep the sub-images apart).
    assert design.pupil_diameter_at_mla / 600e-6 == pytest.approx(5.9375, rel=1e-12)
    assert design.field_of_view_diameter == pytest.approx(66.96e-6, rel=0.01)
    assert all(lens.shape == "square" for lens in design.mla.lenslets)


@pytest.mark.parametrize(("name", "pitch", "focal", "na", "mag"), [
    ("lfm_prevedel2014", 150.0, 3.0, 0.5, 20.0),
    ("lfm_10x_na03", 125.0, 1.875, 0.3, 10.0),
])  # fmt: skip
def test_conventional_presets_put_the_camera_at_the_lenslet_focal_plane(name, pitch, focal, na, mag):
    design = load_preset(name)
    assert design.kind == "conventional" and design.relay is None
    assert isinstance(design.mla, RegularMLASpec)
    assert (design.mla.pitch_um, design.mla.focal_length_mm) == (pitch, focal)
    assert design.mla_to_camera_distance_mm == focal
    assert (design.objective.numerical_aperture, design.objective.magnification) == (na, mag)
    # f-number matched or slower: the pupil images fit in one pitch (within half a 6.5 um pixel).
    assert 2 * design.sub_image_radius / 1e-6 <= pitch + 3.25


def test_resolve_design_takes_a_preset_name_or_a_path(tmp_path, monkeypatch):
    assert resolve_design("flfm_guo2019") == load_preset("flfm_guo2019")
    path = save_design(load_preset("lfm_10x_na03"), tmp_path / "mine.json")
    assert resolve_design(path) == load_preset("lfm_10x_na03")
    assert resolve_design(str(path)) == load_preset("lfm_10x_na03")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "plainname").write_text(path.read_text(encoding="utf-8"), encoding="utf-8")
    assert resolve_design("plainname") == load_preset("lfm_10x_na03")  # not a preset, but a file
    with pytest.raises(
        DesignFileError, match=r"'nope' is neither a preset \(flfm_guo2019, .*\) nor an existing design file"
    ):
        resolve_design("nope")
    with pytest.raises(
        FileNotFoundError, match=r"^design missing.json: no such design file\. Fix: .*xlfm_cong2017"
    ):
        resolve_design("missing.json")
    with pytest.raises(FileNotFoundError, match=r"^--design missing.json: no such design file\. Fix: "):
        resolve_design("missing.json", "--design")


def test_unknown_preset_lists_the_available_ones():
    with pytest.raises(
        DesignFileError, match=r"no preset named 'xlfm'; available: flfm_guo2019, lfm_10x_na03"
    ):
        load_preset("xlfm")


def test_presets_build_editable_explicit_mlas():
    explicit = load_preset("lfm_10x_na03").mla.to_explicit()
    assert isinstance(explicit, MLASpec) and explicit.count == 106 * 106
