"""Per-lenslet Fourier PSF: a lenslet (a coherent group) whose window misses the sensor is
skipped, with the same result as computing it and dropping it, and a PSF that no lenslet
reaches says so."""

from __future__ import annotations

import dataclasses
import warnings

import pytest
import torch

from lfm_studio.engine.design.errors import DesignWarning
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.systems import fourier_psf
from lfm_studio.engine.systems.fourier_psf import (
    FourierAccuracy,
    FourierPSFReport,
    _group_canvas,
    fourier_psf_stack,
    overlap_groups,
    resolve_method,
)
from lfm_studio.engine.systems.fourier_system import FourierLFMSystem
from lfm_studio.engine.systems.lenslet_cache import LensletCache
from lfm_studio.engine.units import mm, nm, um

LENSES = (
    Lenslet((0.1 * mm, -0.05 * mm), 0.25 * mm, 5 * mm, "circle"),
    Lenslet((-0.2 * mm, 0.2 * mm), 0.25 * mm, 5 * mm, "square"),
)
OBJECTIVE = ObjectiveLens(20.0, 0.5, 1.33, 180 * mm)
SYSTEM = FourierLFMSystem(OBJECTIVE, 60 * mm, MicrolensArray(LENSES), 5 * mm, 8 * um, (36, 36), 525 * nm)
ACCURACY = FourierAccuracy(oversampling=2, margin_airy=4)
DEPTHS = (-4 * um, 0.0, 3 * um)


def _unskipped(monkeypatch, system, accuracy, depths):
    """The stack with every window treated as on the sensor (computed, then cropped at placing)."""
    report = FourierPSFReport()
    with monkeypatch.context() as patch:
        patch.setattr(fourier_psf, "_window_on_sensor", lambda *_: True)
        data = fourier_psf_stack(system, depths, accuracy=accuracy, report=report).data
    return data, report


def test_a_lenslet_off_the_sensor_is_skipped_with_the_same_result(monkeypatch):
    """36 x 36 px sensor: lenslet 0's 15 px window starts at (4, 23) (partly on it), lenslet 1's
    at (36, -14): below the last row, so nothing of it is computed or cached."""
    _, windows = resolve_method(SYSTEM, DEPTHS, ACCURACY)
    assert [(w.first_pixel, w.pixels(2)) for w in windows] == [((4, 23), 15), ((36, -14), 15)]
    reference, full = _unskipped(monkeypatch, SYSTEM, ACCURACY, DEPTHS)
    assert full.lenslets_computed == [0, 1] and full.lenslets_off_sensor == []
    report, cache = FourierPSFReport(), LensletCache(2**20)
    data = fourier_psf_stack(SYSTEM, DEPTHS, accuracy=ACCURACY, report=report, cache=cache).data
    assert torch.equal(data, reference) and float(data.sum()) > 0.0
    assert report.lenslets_computed == [0] and report.lenslets_off_sensor == [1]
    assert len(cache) == 1
    again = FourierPSFReport()
    fourier_psf_stack(SYSTEM, DEPTHS, accuracy=ACCURACY, report=again, cache=cache)
    assert again.lenslets_cached == [0] and again.lenslets_off_sensor == [1] and not again.lenslets_computed


def test_no_lenslet_on_the_sensor_gives_zeros_and_a_warning(monkeypatch):
    tiny = dataclasses.replace(SYSTEM, sensor_shape=(8, 8))
    reference, _ = _unskipped(monkeypatch, tiny, ACCURACY, DEPTHS)
    report = FourierPSFReport()
    with pytest.warns(DesignWarning, match=r"no lenslet's light reaches the 8 x 8 px sensor .*PSF is zero"):
        data = fourier_psf_stack(tiny, DEPTHS, accuracy=ACCURACY, report=report).data
    assert torch.equal(data, reference) and not data.any() and data.shape == (3, 8, 8)
    assert report.lenslets_off_sensor == [0, 1] and not report.lenslets_computed
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # one lenslet on the sensor: no warning
        fourier_psf_stack(SYSTEM, DEPTHS, accuracy=ACCURACY)


def test_a_coherent_group_is_skipped_only_when_its_whole_canvas_misses(monkeypatch):
    """A lone lenslet on the axis and a touching pair 1.2-1.6 mm off it; on 64 x 64 px the pair's
    shared canvas starts at pixel (107, 132), off the sensor: skipped with the same result."""
    mla = MicrolensArray(
        tuple(
            Lenslet(c, 0.4 * mm, 16 * mm, "square")
            for c in ((0.0, 0.0), (1.2 * mm, 1.2 * mm), (1.6 * mm, 1.2 * mm))
        )
    )
    system = FourierLFMSystem(OBJECTIVE, 60 * mm, mla, 16 * mm, 8 * um, (64, 64), 525 * nm)
    accuracy = FourierAccuracy(oversampling=2, margin_airy=16, method="per_lenslet_coherent")
    depths = (-10 * um, 10 * um)
    _, windows = resolve_method(system, depths, accuracy)
    assert overlap_groups(system, windows) == [[0], [1, 2]]
    assert _group_canvas(windows, [1, 2], 2) == ((107, 132), 300)
    reference, full = _unskipped(monkeypatch, system, accuracy, depths)
    assert sorted(full.lenslets_computed) == [0, 1, 2]
    report = FourierPSFReport()
    data = fourier_psf_stack(system, depths, accuracy=accuracy, report=report).data
    assert torch.equal(data, reference) and float(data.sum()) > 0.0
    assert report.lenslets_computed == [0] and report.lenslets_off_sensor == [1, 2]
    assert report.coherent_groups == [[1, 2]]
    # A sensor that reaches the canvas computes the whole group (a member's own window may still miss).
    wide = dataclasses.replace(system, sensor_shape=(232, 232))
    report = FourierPSFReport()
    fourier_psf_stack(wide, depths, accuracy=accuracy, report=report)
    assert sorted(report.lenslets_computed) == [0, 1, 2] and report.lenslets_off_sensor == []
