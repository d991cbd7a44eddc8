"""Design files: readable JSON, exact round trips, clear errors, migrations, atomic no-clobber saves."""

from __future__ import annotations

import json
import os

import pytest

from lfm_studio.engine.design import (
    SCHEMA_VERSION,
    Design,
    DesignFileError,
    design_from_json,
    design_io,
    design_to_json,
    list_presets,
    load_design,
    load_preset,
    save_design,
)


@pytest.mark.parametrize("name", list_presets())
def test_every_preset_round_trips_through_a_file_exactly(tmp_path, name):
    original = load_preset(name)
    path = save_design(original, tmp_path / f"{name}.json")
    again = load_design(path)
    assert again == original  # float repr round-trips exactly: equality, not approx
    assert design_to_json(again) == path.read_text(encoding="utf-8")  # writing is deterministic


def test_file_is_human_readable_with_units_in_keys(tmp_path, fourier):
    text = design_to_json(fourier)
    lines = text.splitlines()
    assert lines[0] == "{" and lines[1] == f'  "schema_version": {SCHEMA_VERSION},'  # indent 2, version first
    for key in ("wavelength_nm", "tube_lens_focal_length_mm", "pixel_pitch_um", "center_um", "aperture_diameter_um",
                "focal_length_mm", "mla_to_camera_distance_mm", "depth_range_um", "depth_step_um"):  # fmt: skip
        assert f'"{key}"' in text
    lenslet_lines = [line for line in lines if '"center_um"' in line]
    assert len(lenslet_lines) == fourier.mla.count  # one lenslet per line
    assert max(len(line) for line in lines if '"source"' not in line and '"description"' not in line) <= 130
    assert json.loads(text)["camera"]["pixel_count"] == [512, 512]


def test_not_json_error_names_file_line_and_column(tmp_path):
    path = tmp_path / "broken.json"
    path.write_text('{\n  "schema_version": 1,\n  "name": oops\n}\n', encoding="utf-8")
    with pytest.raises(
        DesignFileError, match=r"broken\.json is not valid JSON: Expecting value at line 3, column 11"
    ):
        load_design(path)
    with pytest.raises(DesignFileError, match=r"must hold a JSON object \(a design\); got a list"):
        design_from_json("[1, 2]")


def _data(design: Design) -> dict:
    return json.loads(design_to_json(design))


def test_unknown_keys_are_listed_with_their_location_and_known_keys(fourier):
    data = _data(fourier)
    data["objective"]["magnificaton"] = 40
    data["mla"]["lenslets"][2]["tilt_deg"] = 1.0
    data["colour"] = "red"
    with pytest.raises(DesignFileError) as info:
        design_from_json(json.dumps(data), origin="my.json")
    message = str(info.value)
    assert "my.json (schema_version 1) has 3 unknown key(s)" in message
    assert (
        "'objective.magnificaton' is not known to any schema version (0-1); keys known in objective: magnification,"
        in message
    )
    assert "'mla.lenslets[2].tilt_deg' is not known to any schema version" in message
    assert "keys known in mla.lenslets[2]: center_um, aperture_diameter_um, focal_length_mm, shape" in message
    assert (
        "'colour' is not known to any schema version (0-1); keys known at the top level: schema_version,"
        in message
    )


def test_a_key_from_an_older_schema_says_which_version_knew_it(fourier):
    data = _data(fourier)
    data["wavelength_um"] = data.pop("wavelength_nm") / 1000
    with pytest.raises(
        DesignFileError, match=r"'wavelength_um' is known to schema_version 0 \(replaced by wavelength_nm"
    ):
        design_from_json(json.dumps(data))


def test_newer_schema_version_is_refused(fourier):
    data = {**_data(fourier), "schema_version": SCHEMA_VERSION + 1}
    with pytest.raises(
        DesignFileError,
        match=r"written by a newer lfm_studio \(schema_version 2\); this lfm_studio reads schema_version 1 and older\. Fix: upgrade",
    ):
        design_from_json(json.dumps(data))


@pytest.mark.parametrize("version", [None, "1", 1.0, True, -1])
def test_missing_or_invalid_schema_version(fourier, version):
    data = _data(fourier)
    if version is None:
        del data["schema_version"]
    else:
        data["schema_version"] = version
    with pytest.raises(
        DesignFileError, match=r"needs an integer schema_version >= 0; got .*Fix: add \"schema_version\": 1"
    ):
        design_from_json(json.dumps(data))


def test_v0_file_is_migrated_wavelength_um_to_nm(tmp_path, fourier):
    data = _data(fourier)
    data["schema_version"] = 0
    data["wavelength_um"] = 0.68
    del data["wavelength_nm"]
    path = tmp_path / "old.json"
    path.write_text(json.dumps(data, indent=2), encoding="utf-8")
    design = load_design(path)
    # Exact decimal scaling: 0.68 um -> 680.0 nm exactly (0.68 * 1000 would give 680.0000000000001).
    assert design.wavelength_nm == 680.0 and design.schema_version == SCHEMA_VERSION
    assert design == fourier
    both = {**data, "wavelength_nm": 680.0}
    with pytest.raises(DesignFileError, match=r"must not hold both wavelength_um and wavelength_nm"):
        design_from_json(json.dumps(both))


def test_invalid_physics_in_a_file_names_the_file_and_the_parameter(fourier):
    data = _data(fourier)
    data["objective"]["numerical_aperture"] = 1.2
    with pytest.raises(
        DesignFileError,
        match=r"x\.json does not describe a valid design: 'objective': .*numerical_aperture 1\.2 must be below immersion_index 1",
    ):
        design_from_json(json.dumps(data), origin="x.json")


def test_missing_key_is_named_without_a_pydantic_dump(fourier):
    data = _data(fourier)
    del data["camera"]["pixel_count"]
    with pytest.raises(DesignFileError) as caught:
        design_from_json(json.dumps(data), origin="x.json")
    message = str(caught.value)
    assert "the key 'camera.pixel_count' is missing (keys of camera: pixel_pitch_um, pixel_count" in message
    assert "Fix:" in message and "errors.pydantic.dev" not in message and "input_type" not in message


GENERIC_FIX = "Fix: add or correct these keys"


def test_a_value_error_with_its_own_fix_gets_no_second_generic_fix(fourier):
    data = _data(fourier)
    data["depths"]["depth_step_um"] = -10
    with pytest.raises(DesignFileError) as caught:
        design_from_json(json.dumps(data), origin="x.json")
    message = str(caught.value)
    assert "depth_step_um must be a finite number > 0 um; got -10 um. Fix: e.g. 2." in message
    assert message.count("Fix:") == 1 and GENERIC_FIX not in message


@pytest.mark.parametrize(
    ("section", "key", "value"),
    [("camera", "pixel_count", None), ("camera", "pixel_pitch_um", "abc")],
    ids=["missing-key", "not-a-number"],
)
def test_missing_keys_and_type_errors_keep_the_generic_fix(fourier, section, key, value):
    """Neither pydantic's "missing" nor its type error carries a fix of ours: the generic one stays."""
    data = _data(fourier)
    if value is None:
        del data[section][key]
    else:
        data[section][key] = value
    with pytest.raises(DesignFileError) as caught:
        design_from_json(json.dumps(data), origin="x.json")
    assert f"'{section}.{key}'" in str(caught.value) and GENERIC_FIX in str(caught.value)


def test_save_never_overwrites_without_being_asked(tmp_path, fourier, conventional):
    path = save_design(fourier, tmp_path / "d.json")
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match=r"d\.json already exists\. Fix: pass overwrite=True"):
        save_design(conventional, path)
    assert path.read_bytes() == before
    save_design(conventional, path, overwrite=True)
    assert load_design(path) == conventional
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.json"]  # no temporary files left


@pytest.mark.parametrize("failing", ["replace", "fsync"])
def test_failed_save_keeps_the_old_file_and_leaves_no_temp_file(
    tmp_path, monkeypatch, fourier, conventional, failing
):
    path = save_design(fourier, tmp_path / "d.json")
    before = path.read_bytes()

    def boom(*args, **kwargs):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(design_io.os, failing, boom)
    with pytest.raises(OSError, match="simulated"):
        save_design(conventional, path, overwrite=True)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.json"]


def test_failed_serialisation_touches_nothing(tmp_path, monkeypatch, fourier):
    path = tmp_path / "new.json"

    def boom(design):
        raise ValueError("cannot serialise (simulated)")

    monkeypatch.setattr(design_io, "design_to_json", boom)
    with pytest.raises(ValueError, match="simulated"):
        save_design(fourier, path)
    assert list(tmp_path.iterdir()) == []


def test_save_keeps_the_file_mode_and_refuses_folders(tmp_path, fourier):
    path = save_design(fourier, tmp_path / "d.json")
    os.chmod(path, 0o640)
    save_design(fourier, path, overwrite=True)
    assert path.stat().st_mode & 0o777 == 0o640
    with pytest.raises(IsADirectoryError, match="is a folder"):
        save_design(fourier, tmp_path)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        save_design(fourier, tmp_path / "missing" / "d.json")
    with pytest.raises(TypeError, match="design must be a Design"):
        save_design({"name": "x"}, tmp_path / "x.json")  # type: ignore[arg-type]


def test_a_missing_design_file_is_named_with_the_fix(tmp_path):
    with pytest.raises(
        FileNotFoundError,
        match=r"design file .*nope\.json does not exist\. Fix: check the path .*load_preset\(name\)",
    ):
        load_design(tmp_path / "nope.json")
    with pytest.raises(FileNotFoundError, match=r"is a folder, not a design file\. Fix"):
        load_design(tmp_path)


def test_regular_mla_file_stays_compact(conventional):
    data = _data(conventional)
    assert data["mla"]["layout"] == "regular" and "lenslets" not in data["mla"]
    del data["mla"]["layout"]  # hand-written files may leave the tag out: pitch_um says "regular"
    assert design_from_json(json.dumps(data)) == conventional


def test_a_rings_lattice_round_trips_through_a_file(tmp_path, fourier):
    from lfm_studio.engine.design import RegularMLASpec

    mla = RegularMLASpec(lattice="rings", pitch_um=600.0, shape=(3, 3), focal_length_mm=16.8)
    design = fourier.updated(mla=mla)
    path = save_design(design, tmp_path / "rings.json")
    again = load_design(path)
    assert again == design and again.mla.lattice == "rings" and again.mla.count == 7
    assert again.mla.lenslets == design.mla.lenslets
    assert json.loads(path.read_text(encoding="utf-8"))["mla"]["lattice"] == "rings"
