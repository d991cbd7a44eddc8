"""The linear methods on a noisy camera image: the frame minus its noise floor, not clipped.

A camera image in photons carries the camera's noise floor ``c`` (:func:`counts_to_photons`),
which every front end passes as the method's ``background``. Tikhonov and Wiener are linear:
clipping ``frame - c`` at 0 kept the positive half of the zero-mean read noise (about
0.4 sigma per pixel, more light than the whole signal here) and the inverse spread it through
the volume. References: the ground truth's photons (:func:`photons_per_unit`, Tikhonov is in
photons per voxel) and the same method on the noise-free image.

Tolerance 0.1: the read noise (1.5 e-, QE 0.8: sigma about 1.9 photons per pixel) moves the
image's total by sqrt(pixels) * 1.9 photons, 2.2 % of 1e4 photons on the conventional 114^2
image and 1.6 % of 3e4 on the Fourier 256^2 one; the clipped frame was off by 1.5x to 4.7x.
"""

from __future__ import annotations

import pytest

from lfm_studio.engine.io.camera_counts import counts_to_photons, design_camera
from lfm_studio.engine.reconstruct import reconstruct_frame
from lfm_studio.engine.simulation import camera_of, light_field_image, photons_per_unit
from tests.engine.reconstruct.conftest import System, bead_phantom

TOLERANCE = 0.1


def _totals(system: System, setup, method: str, photons: float, count: int, seed: int) -> tuple[float, ...]:
    """(noisy volume, noise-free volume, truth) photon totals for a bead phantom imaged by ``system``'s camera."""
    phantom = bead_phantom(setup, count=count, seed=seed).data
    counts, expected = light_field_image(setup, phantom, camera_of(system.design), photons=photons, seed=0)
    scale = photons_per_unit(expected, photons)
    frame, floor = counts_to_photons(counts, design_camera(system.design.camera), name="image")
    assert floor > 0  # the camera's floor is there, and below passed as the background (as the front ends do)
    noisy = reconstruct_frame(setup.projector, frame, method=method, background=floor)
    noise_free = reconstruct_frame(setup.projector, expected * scale, method=method)
    return (
        float(noisy.double().sum()),
        float(noise_free.double().sum()),
        float(phantom.double().sum()) * scale,
    )


def test_tikhonov_on_a_noisy_conventional_image_keeps_the_truths_photons(conventional):
    noisy, noise_free, truth = _totals(conventional, conventional.setup64, "tikhonov", 1e4, count=4, seed=0)
    assert noisy / truth == pytest.approx(1.0, abs=TOLERANCE)
    assert noisy / noise_free == pytest.approx(1.0, abs=TOLERANCE)


@pytest.mark.parametrize("method", ["wiener", "tikhonov"])
def test_linear_methods_on_a_noisy_fourier_image_match_the_noise_free_run(fourier, method):
    """Wiener is not in photons per voxel (each depth holds the image's light): the noise-free run is its reference."""
    noisy, noise_free, _ = _totals(fourier, fourier.setup, method, 3e4, count=3, seed=6)
    assert noisy / noise_free == pytest.approx(1.0, abs=TOLERANCE)
