"""Sample data: a simulated bead light-field image with its PSF stack and ground truth.

Computed on request (nothing is downloaded) and seeded, so the same call gives the
same layers: the ``flfm_guo2019`` preset (Fourier LFM, 3 x 3 lenslets, 40x/0.95) on a
288 x 288 pixel crop of its camera (every sub-image still lands on it) at 5 depths
from -20 to 20 um, 8 beads and 1e6 photons with shot and read noise. About 2 s on a
laptop CPU. The image is in camera counts (ADU) with the camera's 100 ADU baseline,
recorded with the gain and QE in its metadata, so the Reconstruct widget turns it
back into photons by itself. The ground truth is in photons per voxel (the phantom times
:func:`~lfm_studio.engine.simulation.photons_per_unit`, as ``lfm-studio image --truth`` writes
it): the unit a reconstruction comes out in, so the two layers compare directly; its
projection puts the 1e6 photons on the camera.
"""

from __future__ import annotations

from lfm_studio.engine.design import Design, load_preset
from lfm_studio.engine.io import LightFieldImage, Volume, camera_metadata
from lfm_studio.engine.io.camera_counts import ADU
from lfm_studio.engine.simulation import (
    camera_of,
    design_depths,
    imaging_setup,
    light_field_image,
    make_phantom,
    photons_per_unit,
    simulate_psf,
)
from lfm_studio.napari_plugin.layer_data import (
    LayerData,
    light_field_layer_data,
    psf_layer_data,
    volume_layer_data,
)

PRESET = "flfm_guo2019"
SENSOR_PIXELS = 288  # 288 x 6.5 um = 1.87 mm: the 3 x 3 sub-images of 600 um lenslets fit
DEPTHS_UM = (-20.0, 20.0, 10.0)  # start, stop, step
BEADS = 8
PHOTONS = 1e6
SEED = 0
NAMES = ("beads light field", "beads PSF stack", "beads ground truth")
TRUTH_UNITS = "photons per voxel"


def sample_design() -> Design:
    """The reduced preset the sample is simulated with (a smaller camera, 5 depths)."""
    design = load_preset(PRESET)
    camera = design.camera.model_dump()
    camera["pixel_count"] = (SENSOR_PIXELS, SENSOR_PIXELS)
    start, stop, step = DEPTHS_UM
    return design.updated(
        name=f"{design.name} (sample: {SENSOR_PIXELS} px camera)",
        camera=camera,
        depths={"depth_range_um": (start, stop), "depth_step_um": step},
    )


def bead_sample(seed: int = SEED) -> list[LayerData]:
    """The three sample layers: light-field image (ADU), PSF stack, ground-truth volume (photons per
    voxel) (napari sample hook)."""
    design = sample_design()
    stack = simulate_psf(design, depths=design_depths(design))
    setup = imaging_setup(stack)
    volume, info = make_phantom("beads", setup, seed=seed, count=BEADS)
    counts, expected = light_field_image(setup, volume, camera_of(design), photons=PHOTONS, seed=seed)
    provenance = {**info, "photons": PHOTONS, "design": design.name, "psf": NAMES[1]}
    camera = {"units": ADU, "camera": camera_metadata(camera_of(design), photons=PHOTONS, seed=seed)}
    image = LightFieldImage(counts.cpu(), stack.pixel_size, {**provenance, **camera})
    photons = volume * photons_per_unit(expected, PHOTONS)  # photons per voxel, as `image --truth`
    truth = Volume(photons.cpu(), setup.voxel_size, stack.depths, {**provenance, "units": TRUTH_UNITS})
    lf, psf, gt = NAMES
    return [
        volume_layer_data(truth, name=gt),
        psf_layer_data(stack, name=psf),
        light_field_layer_data(image, name=lf),
    ]
