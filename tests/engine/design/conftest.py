"""Small, valid designs to start tests from (built in code, independent of the presets)."""

from __future__ import annotations

import pytest

from lfm_studio.engine.design import (
    CameraSpec,
    DepthSpec,
    Design,
    MLASpec,
    ObjectiveSpec,
    RegularMLASpec,
    RelayLensSpec,
)


def make_fourier(**changes) -> Design:
    """A Guo-2019-like FLFM: 40x/0.95 air, 75 mm Fourier lens, 3 x 3 square 600 um lenslets, f 16.8 mm."""
    fields = dict(
        name="test FLFM",
        kind="fourier",
        wavelength_nm=680.0,
        objective=ObjectiveSpec(
            magnification=40.0, numerical_aperture=0.95, immersion_index=1.0, tube_lens_focal_length_mm=200.0
        ),
        relay=RelayLensSpec(focal_length_mm=75.0, field_stop_diameter_mm=2.66),
        mla=MLASpec.square_grid(600.0, 3, 16.8, lenslet_shape="square"),
        mla_to_camera_distance_mm=16.8,
        camera=CameraSpec(pixel_pitch_um=6.5, pixel_count=(512, 512)),
        depths=DepthSpec(depth_range_um=(-10.0, 10.0), depth_step_um=5.0),
    )
    fields.update(changes)
    return Design(**fields)


def make_conventional(**changes) -> Design:
    """The issue's 10x/0.3 conventional LFM: 125 um pitch, 1875 um focal length, 6.5 um pixels, 525 nm."""
    fields = dict(
        name="test LFM",
        kind="conventional",
        wavelength_nm=525.0,
        objective=ObjectiveSpec(
            magnification=10.0, numerical_aperture=0.3, immersion_index=1.0, tube_lens_focal_length_mm=200.0
        ),
        mla=RegularMLASpec(pitch_um=125.0, shape=(20, 20), focal_length_mm=1.875, lenslet_shape="square"),
        mla_to_camera_distance_mm=1.875,
        camera=CameraSpec(pixel_pitch_um=6.5, pixel_count=(384, 384)),
        depths=DepthSpec(depth_range_um=(-50.0, 50.0), depth_step_um=10.0),
    )
    fields.update(changes)
    return Design(**fields)


@pytest.fixture
def fourier() -> Design:
    return make_fourier()


@pytest.fixture
def conventional() -> Design:
    return make_conventional()
