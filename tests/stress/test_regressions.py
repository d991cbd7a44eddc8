"""Regression guards for the torch 2048 x 2048 FFT bug (docs/platform.md) at the level of the engine's users.

torch 2.13.0+cpu with 2 threads scales scaled-direction 2D transforms of exactly 2048^2
complex64 by an extra 1/N^2; ``engine/fft.py`` only asks torch for unscaled transforms
(``tests/engine/test_fft.py`` tests it directly). Here the propagator and the projector, which
hit FFT sizes of exactly 2048, must conserve power, round-trip and reproduce a PSF, at 1 and 2
threads. The other guards of the issue live with their subjects: the float32 phase of long
propagations (``test_propagation_extremes.py``), the Wiener filter at SNR -> 0 and infinity
and RL on an all-zero image (``test_reconstruction_extremes.py``).
"""

from __future__ import annotations

import pytest
import torch

from lfm_studio.engine.operators import ShiftInvariantProjector
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.propagation import propagate
from lfm_studio.engine.optics.sources import gaussian_beam
from lfm_studio.engine.units import nm, um

THREADS = pytest.mark.parametrize("threads", [1, 2], ids=["1thread", "2threads"])


@THREADS
def test_propagation_on_an_exactly_2048_grid_conserves_power_and_round_trips(threads):
    assert torch.get_num_threads() == threads  # set by the conftest fixture from the parameter
    field = gaussian_beam(Grid(2048, 1 * um), 520 * nm, 160 * um, dtype=torch.complex64)
    forward = propagate(field, 2e-3, method="bandlimited_asm", padding=1.0, cache=False)
    back = propagate(forward, -2e-3, method="bandlimited_asm", padding=1.0, cache=False)
    # A unit-modulus kernel within the band (the beam's spectrum is far inside it): power kept to
    # complex64 FFT rounding (measured ~1e-7; bound 1e-5). The bug would give a ratio of 6e-14.
    ratio = float(forward.power().double() / field.power().double())
    assert abs(ratio - 1.0) < 1e-5
    error = float((back.data - field.data).abs().max() / field.data.abs().max())
    assert error < 1e-5


@THREADS
def test_projector_with_an_fft_window_of_exactly_2048_reproduces_its_psf(threads):
    # V + P - 1 = 2048: the forward projection of one voxel at the volume centre is the PSF itself.
    gen = torch.Generator().manual_seed(threads)
    psf = torch.rand((1, 1024, 1024), generator=gen)
    projector = ShiftInvariantProjector(psf, (1025, 1025))
    assert projector.fft_shape == (2048, 2048)
    volume = torch.zeros(projector.volume_shape)
    volume[0, 512, 512] = 1.0
    image = projector.forward(volume)
    # float32 FFT convolution: error ~ eps log2(N) of the largest value (measured ~1e-7); bound 1e-5.
    assert float((image - psf[0]).abs().max() / psf.max()) < 1e-5
    back = projector.adjoint(image)
    # A^T A delta at the centre voxel is sum(psf^2) (the autocorrelation peak).
    expected = float((psf.double() ** 2).sum())
    assert float(back[0, 512, 512]) == pytest.approx(expected, rel=1e-5)
