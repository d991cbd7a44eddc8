"""A bead volume seen by a misaligned Fourier LFM, with its radiometry and dark frames (tests, demos).

The nominal instrument is ``flfm_guo2019`` on a ``RAW_SHAPE`` camera crop with 3 depths
(-20, 0, 20 um). The built instrument differs: its sub-image centres are the nominal ones
turned by 1.1 deg about the axis pixel, scaled by 1.004, shifted by (2.2, -1.7) px and
jittered by 0.3 px rms (:func:`~lfm_studio.engine.calibration.synthetic.fourier_frames`),
and each sub-image has its own gain (``GAINS``, 0.6 to 1.25) on top of a 30 % radial
vignetting. The true instrument's design (lenslets at the true centres) images six beads
through our own forward model; the raw frame then gets the vignetting, Poisson and read
noise (1.5 e-), a 100 ADU dark offset and the sensor's 0.1 % hot pixels (the same in every
frame, as on a real camera; gain 1 ADU per electron).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from lfm_studio.engine.calibration.fitted_design import mla_at_centres
from lfm_studio.engine.calibration.nominal import nominal_sub_images
from lfm_studio.engine.calibration.sub_image_flat import SubImageFlat, sub_image_flat_map
from lfm_studio.engine.calibration.synthetic import expose, fourier_frames, radial_vignetting
from lfm_studio.engine.design import Design, load_preset
from lfm_studio.engine.phantoms import beads
from lfm_studio.engine.simulation import imaging_setup, simulate_psf

RAW_SHAPE = (288, 288)
BASELINE_ADU = 100.0
HOT_ADU = 3000.0  # as in fourier_frames
GAINS = torch.tensor([1.0, 0.7, 1.25, 0.85, 1.1, 0.6, 0.95, 1.2, 0.75], dtype=torch.float64)


@dataclass(frozen=True)
class MisalignedFourierScene:
    """Frames (ADU, float64) and truth of :func:`misaligned_fourier_scene`.

    Attributes
    ----------
    nominal : the nominal design (what ``calibrate`` gets).
    true_design : the built instrument (lenslets at the true sub-image centres).
    truth : (Z, Y, X) bead volume on the true design's voxel grid.
    raw, radiometry, dark : raw camera frames, ``RAW_SHAPE``.
    centres : (L, 2) true sub-image centres, px.
    bead_scan : (Z, Y, X) raw frames of one bead at the centre of each depth (a measured PSF).
    """

    nominal: Design
    true_design: Design
    truth: torch.Tensor
    raw: torch.Tensor
    radiometry: torch.Tensor
    dark: torch.Tensor
    centres: torch.Tensor
    bead_scan: torch.Tensor


def _vignetting(design: Design, centres: torch.Tensor) -> torch.Tensor:
    """Per-sub-image ``GAINS`` inside each sub-image times the 30 % radial vignetting (Y, X)."""
    gains = torch.zeros(len(GAINS), 6, dtype=torch.float64)
    gains[:, 0] = GAINS
    radius = 0.5 * nominal_sub_images(design, RAW_SHAPE).diameter
    return sub_image_flat_map(SubImageFlat(gains, radius), centres, RAW_SHAPE) * radial_vignetting(
        RAW_SHAPE, 0.3
    )


def _camera(electrons: torch.Tensor, hot: torch.Tensor, *, seed: int) -> torch.Tensor:
    """A frame (ADU) of the scene's camera: noise, dark offset, and its hot pixels ``hot`` (Y, X) bool."""
    frame, _, _ = expose(
        electrons,
        baseline_adu=BASELINE_ADU,
        read_noise_e=1.5,
        gain_adu_per_e=1.0,
        hot_fraction=0.0,
        hot_adu=0.0,
        seed=seed,
    )
    return frame + HOT_ADU * hot


def misaligned_fourier_scene(photons: float = 3e6, seed: int = 0) -> MisalignedFourierScene:
    """The scene of the module docstring; ``photons`` in the whole (unvignetted) bead image."""
    base = load_preset("flfm_guo2019")
    nominal = base.updated(
        camera={**base.camera.model_dump(), "pixel_count": RAW_SHAPE},
        depths={"depth_range_um": (-20.0, 20.0), "depth_step_um": 20.0},
    )
    radiometry, dark, centres = fourier_frames(
        nominal, RAW_SHAPE, rotation_deg=1.1, scale=1.004, shift=(2.2, -1.7), gains=GAINS, seed=seed + 6
    )
    mla, _ = mla_at_centres(nominal, centres, RAW_SHAPE)
    true_design = nominal.updated(mla=mla, name="misaligned flfm (truth)")
    setup = imaging_setup(simulate_psf(true_design))
    truth = beads(
        setup.volume_shape,
        count=6,
        voxel_size=setup.voxel_size,
        seed=seed + 3,
        intensity=1.0,
        margin=0.0,
        min_separation=4e-6,
    ).data
    image = setup.projector.forward(truth.float()).clamp_min(0.0).double()
    vignetting = _vignetting(nominal, centres)
    image = image * (photons / float(image.sum())) * vignetting
    hot = dark > BASELINE_ADU + 0.5 * HOT_ADU  # the sensor's hot pixels, the same in every frame
    raw = _camera(image, hot, seed=seed + 2)
    frames = []
    for z in range(setup.volume_shape[0]):  # one bead on the axis at each depth
        point = torch.zeros(setup.volume_shape)
        point[z, setup.volume_shape[1] // 2, setup.volume_shape[2] // 2] = 1.0
        frames.append(setup.projector.forward(point).clamp_min(0.0).double())
    scan = torch.stack(frames)
    scan = scan * (2e6 / float(scan[len(scan) // 2].sum())) * vignetting
    bead_scan = torch.stack([_camera(frame, hot, seed=seed + 4 + z) for z, frame in enumerate(scan)])
    return MisalignedFourierScene(nominal, true_design, truth, raw, radiometry, dark, centres, bead_scan)
