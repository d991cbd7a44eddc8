"""Sample data: three seeded layers (light field, PSF stack, ground truth) with consistent physical scales."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from lfm_studio.engine.simulation import imaging_setup
from lfm_studio.napari_plugin.layer_data import stack_from_layer
from lfm_studio.napari_plugin.sample_data import BEADS, PHOTONS, bead_sample
from lfm_studio.resources_access import resource_path
from tests.napari.conftest import PLUGIN


def _preset() -> dict:
    return json.loads(resource_path("designs", "flfm_guo2019.json").read_text(encoding="utf-8"))


def test_sample_opens_as_three_layers_with_physical_scales(make_napari_viewer):
    viewer = make_napari_viewer()
    viewer.open_sample(PLUGIN, "beads")
    layers = {layer.name: layer for layer in viewer.layers}
    assert set(layers) == {"beads light field", "beads PSF stack", "beads ground truth"}
    lf, psf, gt = layers["beads light field"], layers["beads PSF stack"], layers["beads ground truth"]
    assert [lf.metadata["kind"], psf.metadata["kind"], gt.metadata["kind"]] == [
        "light_field",
        "psf_stack",
        "volume",
    ]
    p = _preset()
    pitch = p["camera"]["pixel_pitch_um"]
    # Fourier LFM magnification M f_mla / f_relay, from the preset's numbers (not the engine's property)
    magnification = (
        p["objective"]["magnification"] * p["mla_to_camera_distance_mm"] / p["relay"]["focal_length_mm"]
    )
    np.testing.assert_allclose(lf.scale, (pitch, pitch), rtol=1e-12)
    np.testing.assert_allclose(psf.scale, (10.0, pitch, pitch), rtol=1e-12)
    np.testing.assert_allclose(gt.scale, (10.0, pitch / magnification, pitch / magnification), rtol=1e-12)
    assert psf.metadata["depths_um"] == gt.metadata["depths_um"] == [-20.0, -10.0, 0.0, 10.0, 20.0]
    assert lf.data.shape == psf.data.shape[1:] == (288, 288)
    # every sub-image lies on the cropped camera: the PSF keeps all it had in the 3 x 3 lenslet field
    assert (
        psf.data[:, 0, :].max() < 1e-3 * psf.data.max() and psf.data[:, :, -1].max() < 1e-3 * psf.data.max()
    )


def test_sample_is_seeded_and_obeys_the_photon_budget(bead_layers):
    (gt, _, _), _, (lf, lf_meta, _) = bead_layers
    again = bead_sample()
    for (a, _, _), (b, _, _) in zip(bead_layers, again, strict=True):
        np.testing.assert_array_equal(a, b)
    assert int((gt > 0).sum()) == BEADS
    p = _preset()["camera"]
    assert lf_meta["metadata"]["metadata"]["camera"]["baseline_adu"] == p["baseline_adu"]
    # counts = gain (QE photons + noise) + baseline: the signal sums to gain QE photons (shot noise ~0.1 %)
    signal = float(lf.astype(np.float64).sum() - p["baseline_adu"] * lf.size)
    expected = p["gain_adu_per_e"] * p["quantum_efficiency"] * PHOTONS
    assert abs(signal / expected - 1) < 0.01, signal / expected


def test_sample_truth_is_in_photons_per_voxel_and_projects_to_the_photon_budget(bead_layers):
    """The truth is in the unit a reconstruction comes out in (docs/napari_plugin.md), as `lfm-studio
    image --truth` writes it: projected through the PSF it puts the image's 1e6 photons on the camera,
    and with a collection efficiency of ~0.08 per depth (the PSF's sum) it holds ~1.25e7 photons."""
    (gt, gt_meta, _), (psf, psf_meta, _), _ = bead_layers
    assert gt_meta["metadata"]["metadata"]["units"] == "photons per voxel"
    stack = stack_from_layer(psf, psf_meta["metadata"], name="psf")
    projector = imaging_setup(stack).projector
    on_camera = float(projector.forward(torch.as_tensor(gt)).clamp_min(0.0).double().sum())
    assert on_camera == pytest.approx(PHOTONS, rel=1e-5)
    per_depth = psf.astype(np.float64).sum(axis=(1, 2))  # photons on the camera per emitted photon
    depth_of_bead = np.nonzero(gt)[0]
    emitted = gt.astype(np.float64)[np.nonzero(gt)]
    # the PSF's sum counts an on-axis bead's light; beads off the axis lose some past the 288 px crop
    # (measured 1.2 % in all), so sum(truth x PSF sum) exceeds the photons on the camera a little
    ratio = float((emitted * per_depth[depth_of_bead]).sum()) / PHOTONS
    assert ratio >= 1.0 - 1e-5, ratio  # no bead delivers more than its depth's PSF sum
    assert ratio < 1.02, ratio  # and the light lost past the crop is small
    # every emitted photon reaches the camera at most with the best depth's efficiency (bead units
    # summed to 8 here)
    assert float(gt.sum()) >= PHOTONS / float(per_depth.max())
