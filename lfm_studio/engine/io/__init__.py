"""File input/output: PSF stacks, volumes and camera images as ImageJ-hyperstack TIFFs.

Files open in Fiji and napari with their physical scale and carry the full
lfm_studio header (depths, pixel size, magnification, wavelength, design) as JSON
in the ImageJ ``Info`` property. Writes are atomic and never overwrite unless asked.

Example::

    from lfm_studio.engine.io import read_psf_stack, read_volume, write_volume
    from lfm_studio.engine.units import nm, um

    write_volume("gt.tif", volume, voxel_size=(2 * um, 0.5 * um, 0.5 * um))
    vol = read_volume("gt.tif")                      # Volume(data, voxel_size, depths, metadata)
    beads = read_psf_stack("beads.tif", magnification=20.0, wavelength=525 * nm,
                           depths=[(i - 25) * 2 * um for i in range(51)])  # a Fiji bead stack
"""

from lfm_studio.engine.io.camera_counts import (
    CameraCalibration,
    camera_metadata,
    counts_to_photons,
    resolve_calibration,
)
from lfm_studio.engine.io.containers import LightFieldImage, Volume
from lfm_studio.engine.io.file_checks import InputFileError, OutputError, check_output
from lfm_studio.engine.io.metadata import SCHEMA_VERSION, HeaderError, MissingMetadataError
from lfm_studio.engine.io.tiff_io import (
    read_image,
    read_psf_stack,
    read_volume,
    write_image,
    write_psf_stack,
    write_volume,
)

__all__ = [
    "SCHEMA_VERSION",
    "CameraCalibration",
    "HeaderError",
    "InputFileError",
    "LightFieldImage",
    "MissingMetadataError",
    "OutputError",
    "Volume",
    "camera_metadata",
    "check_output",
    "counts_to_photons",
    "read_image",
    "read_psf_stack",
    "read_volume",
    "resolve_calibration",
    "write_image",
    "write_psf_stack",
    "write_volume",
]
