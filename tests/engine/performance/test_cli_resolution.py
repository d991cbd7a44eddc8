"""``lfm-studio resolution``: registered in the main parser; table, JSON and named errors."""

from __future__ import annotations

import json
import warnings

import pytest

from lfm_studio.cli import main
from lfm_studio.engine.design import save_design
from tests.engine.performance.test_reconstructed import PIXEL_UM, sampling_limited_design

FAST = ["--crop", "0", "--iterations", "5", "--max-lateral", "3", "--max-axial", "4"]


@pytest.fixture(scope="module")
def design_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("resolution") / "small.json"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # advisories of the small design (sub-images cut by the sensor)
        save_design(sampling_limited_design(1, 64, offset_um=250.0, aperture_um=400.0), path)
    return path


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def test_json_reports_each_depth_with_the_grid_floor(design_file, capsys):
    assert main(["resolution", str(design_file), "--depths", "0,4", "--json", *FAST]) == 0
    data = json.loads(capsys.readouterr().out)
    floor = 2 * PIXEL_UM / (40 * 16.8 / 75)  # 2 voxels of pixel / M_T, um
    assert data["lateral_grid_floor_um"] == pytest.approx(floor, rel=1e-9)
    assert data["axial_grid_floor_um"] == pytest.approx(2 * 2.0)  # the design's 2 um depth step
    assert [d["depth_um"] for d in data["depths"]] == pytest.approx([0.0, 4.0])
    for d in data["depths"]:
        for key, grid in (("lateral_um", floor), ("axial_um", 4.0)):
            assert d[key] is None or d[key] >= grid * (1 - 1e-9)


def test_table_and_the_grid_override(design_file, capsys):
    assert main(["resolution", str(design_file), "--volume-oversampling", "3", *FAST]) == 0
    out = capsys.readouterr().out
    voxel = PIXEL_UM / (3 * 40 * 16.8 / 75)
    assert f"lateral voxel {voxel:.4g} um (grid floor {2 * voxel:.4g} um)" in out
    assert "depth_um" in out and "lateral_um" in out and "axial_um" in out


def test_bad_grid_setting_is_named(design_file, capsys):
    assert main(["resolution", str(design_file), "--volume-oversampling", "2", *FAST]) == 2
    assert "volume_oversampling must be 1, 3, 5 or 7" in capsys.readouterr().err
