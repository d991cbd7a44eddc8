"""Calibration files (save/load round trip, overwrite, version) and the design fitted to a calibration."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import re

import pytest
import torch

from lfm_studio.engine.calibration import (
    CalibrationFileError,
    LensletLattice,
    calibrate,
    calibration_files,
    fitted_design,
    load_calibration,
    rectify_frame,
    save_calibration,
)
from lfm_studio.engine.calibration.synthetic import conventional_design_for, synthetic_frames
from lfm_studio.engine.systems.from_design import conventional_system_of

SHAPE = (320, 352)


@pytest.fixture(scope="module")
def calibrated():
    truth = LensletLattice.from_geometry((17.21, 17.21), math.radians(0.9), (163.4, 171.8))
    frames = synthetic_frames(SHAPE, truth, disk_diameter=15.5, seed=9)
    design = conventional_design_for(17.21, SHAPE)
    return design, frames, calibrate(frames.radiometry, design, dark=frames.dark)


def test_round_trip_keeps_every_measurement(tmp_path, calibrated):
    _, frames, calibration = calibrated
    path = save_calibration(calibration, tmp_path / "calib.json")
    loaded = load_calibration(path)
    assert loaded.kind == calibration.kind and loaded.version == calibration.version
    assert loaded.frame_shape == calibration.frame_shape and loaded.block == calibration.block
    assert loaded.grid.lattice == calibration.grid.lattice  # floats survive JSON exactly
    assert torch.equal(loaded.grid.indices, calibration.grid.indices)
    assert torch.equal(loaded.grid.flags, calibration.grid.flags)
    assert torch.allclose(loaded.grid.measured, calibration.grid.measured, atol=1e-6)
    assert torch.equal(loaded.defects, calibration.defects)
    assert torch.equal(loaded.dark_frame, frames.dark.float())  # stored beside the JSON
    assert torch.allclose(loaded.envelope, calibration.envelope, rtol=1e-12)
    assert loaded.design == calibration.design
    # The loaded calibration rectifies a frame like the original one.
    assert torch.allclose(
        rectify_frame(frames.radiometry, loaded), rectify_frame(frames.radiometry, calibration), rtol=1e-9
    )
    doc = json.loads(path.read_text())
    assert doc["format"] == "lfm_studio.calibration" and doc["version"] == 2
    assert doc["summary"]["pitch_yx_px"] == pytest.approx([17.21, 17.21], abs=0.01)
    # A version-1 file (before the Fourier per-sub-image flat field) still loads, as version 1.
    old = tmp_path / "old.json"
    old.write_text(json.dumps({**doc, "version": 1}))
    assert load_calibration(old).version == 1


def _dark_files(folder):
    return sorted(p.name for p in folder.glob("calib.dark*.npz"))


def test_no_overwrite_without_asking(tmp_path, calibrated):
    _, _, calibration = calibrated
    path = tmp_path / "calib.json"
    path.write_text("keep me")
    with pytest.raises(FileExistsError, match="already exists"):
        save_calibration(calibration, path)
    assert path.read_text() == "keep me" and _dark_files(tmp_path) == []
    path.unlink()
    stray = tmp_path / "calib.dark.npz"
    stray.write_text("keep me too")  # a file no calibration names is never touched
    save_calibration(calibration, path)
    assert stray.read_text() == "keep me too"
    stray.unlink()
    save_calibration(calibration, path, overwrite=True)
    assert load_calibration(path).kind == "conventional"
    (dark,) = _dark_files(tmp_path)
    assert re.fullmatch(r"calib\.dark\.[0-9a-f]{16}\.npz", dark)  # content-addressed
    assert [p.name for p in calibration_files(path)] == ["calib.json", dark]
    assert sorted(p.name for p in tmp_path.iterdir()) == [dark, "calib.json"]  # no temporary files


def _other_dark(calibration):
    return dataclasses.replace(calibration, dark_frame=calibration.dark_frame + 1.0)


def test_replacing_a_calibration_removes_the_old_dark_frame_and_reads_old_files(tmp_path, calibrated):
    _, _, calibration = calibrated
    path = save_calibration(calibration, tmp_path / "calib.json")
    (first,) = _dark_files(tmp_path)
    save_calibration(_other_dark(calibration), path, overwrite=True)
    (second,) = _dark_files(tmp_path)
    assert second != first
    assert torch.equal(load_calibration(path).dark_frame, calibration.dark_frame.float() + 1.0)
    save_calibration(dataclasses.replace(calibration, dark_frame=None), path, overwrite=True)
    assert _dark_files(tmp_path) == [] and load_calibration(path).dark_frame is None
    # A file of an earlier version names its dark frame calib.dark.npz: it loads, and is replaced cleanly.
    save_calibration(calibration, path, overwrite=True)
    (current,) = _dark_files(tmp_path)
    (tmp_path / current).rename(tmp_path / "calib.dark.npz")
    doc = json.loads(path.read_text())
    path.write_text(json.dumps({**doc, "dark_frame": {**doc["dark_frame"], "file": "calib.dark.npz"}}))
    assert torch.equal(load_calibration(path).dark_frame, calibration.dark_frame.float())
    save_calibration(_other_dark(calibration), path, overwrite=True)
    assert _dark_files(tmp_path) == [second]


class _Interrupt:
    """Replaces ``os.replace`` and ``os.unlink``: counts the file-system changes and raises
    KeyboardInterrupt (as a Ctrl+C would) before change number ``at``."""

    def __init__(self, monkeypatch, at):
        self.count, self.at = 0, at
        for name in ("replace", "unlink"):
            original = getattr(os, name)
            monkeypatch.setattr(os, name, self._wrap(original))

    def _wrap(self, original):
        def changed(*args, **kwargs):
            if self.count == self.at:
                self.count += 1
                raise KeyboardInterrupt
            self.count += 1
            return original(*args, **kwargs)

        return changed


@pytest.mark.parametrize("at", range(4))
def test_an_interrupt_at_any_step_of_a_replacement_leaves_the_old_or_the_new_calibration(
    tmp_path, calibrated, monkeypatch, at
):
    _, _, calibration = calibrated
    path = save_calibration(calibration, tmp_path / "calib.json")
    new = _other_dark(calibration)
    with monkeypatch.context() as patch:
        interrupt = _Interrupt(patch, at)
        with contextlib.suppress(KeyboardInterrupt):
            save_calibration(new, path, overwrite=True)
    loaded = load_calibration(path).dark_frame  # never "SHA-256 differs" nor a missing file
    assert torch.equal(loaded, calibration.dark_frame.float()) or torch.equal(loaded, new.dark_frame.float())
    if interrupt.count <= at:  # the save finished before the interrupt: the new one, and no leftover
        assert torch.equal(loaded, new.dark_frame.float()) and len(_dark_files(tmp_path)) == 1


def test_unreadable_files_name_the_problem(tmp_path, calibrated):
    _, _, calibration = calibrated
    path = save_calibration(calibration, tmp_path / "calib.json")
    doc = json.loads(path.read_text())
    newer = tmp_path / "newer.json"
    newer.write_text(json.dumps({**doc, "version": 99}))
    with pytest.raises(CalibrationFileError, match=r"version 99.*Fix: upgrade"):
        load_calibration(newer)
    other = tmp_path / "design.json"
    other.write_text(json.dumps({"schema_version": 1}))
    with pytest.raises(CalibrationFileError, match="not an lfm_studio calibration"):
        load_calibration(other)
    (dark,) = _dark_files(tmp_path)
    (tmp_path / dark).write_bytes(b"not the dark frame")
    with pytest.raises(CalibrationFileError, match=rf"{re.escape(dark)} is not the one .*SHA-256"):
        load_calibration(path)
    (tmp_path / dark).unlink()
    with pytest.raises(CalibrationFileError, match=rf"needs its dark frame .*{re.escape(dark)}.*Fix"):
        load_calibration(path)
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps({k: v for k, v in doc.items() if k != "lattice"} | {"lenslets": None}))
    with pytest.raises(CalibrationFileError):
        load_calibration(broken)


def test_rectified_frame_matches_the_fitted_design(calibrated):
    design, frames, calibration = calibrated
    fitted = fitted_design(design, calibration)
    assert fitted_design(None, calibration) == fitted  # the nominal design is stored in the calibration
    lattice = calibration.grid.lattice
    assert fitted.mla.pitch_um == pytest.approx(
        math.sqrt(lattice.pitch[0] * lattice.pitch[1]) * 6.5, rel=1e-12
    )
    assert fitted.mla.pitch_um == pytest.approx(17.21 * 6.5, abs=0.01 * 6.5)
    # The array (even count) is centred half a pitch from the lattice origin, relative to pixel (Y//2, X//2).
    ox, oy = fitted.mla.offset_um
    centre = torch.tensor([oy / 6.5 + SHAPE[0] // 2, ox / 6.5 + SHAPE[1] // 2], dtype=torch.float64)
    ij = lattice.lattice_coordinates(centre)
    assert torch.allclose(ij - ij.floor(), torch.tensor([0.5, 0.5], dtype=torch.float64), atol=1e-9)
    assert fitted.camera.pixel_count == SHAPE
    system = conventional_system_of(fitted)
    image = rectify_frame(frames.radiometry, calibration, lenslets=(9, 11))
    assert image.shape == (9 * system.pixels_per_lenslet, 11 * system.pixels_per_lenslet)
    series = rectify_frame(
        torch.stack((frames.radiometry, 2 * frames.radiometry)), calibration, lenslets=(9, 11)
    )
    assert series.shape == (2, *image.shape) and torch.equal(series[0], image)
    assert re.search(r"rotation (0\.89\d\d|0\.90\d\d) deg", fitted.assumed[-1])
