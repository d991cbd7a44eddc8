"""Calibration of real light-field data: lenslet grid, corrections, rectification, calibration files.

From a radiometry frame (a uniform fluorescent slide through the MLA) and an optional
dark frame, :func:`calibrate` measures the lenslet lattice of a conventional LFM (pitch per
axis, rotation, offset; centroids per lenslet with residuals and outlier flags) or the
sub-image centres of a Fourier LFM, the dark level, defective pixels and the flat-field
envelope. :func:`rectify_frame` turns a raw frame into the image the design's projector
expects, :func:`fitted_design` builds the design that matches the instrument, and
:func:`save_calibration` / :func:`load_calibration` keep it in a versioned JSON file.

Example::

    from lfm_studio.engine.calibration import calibrate, load_calibration, rectify_frame, save_calibration
    from lfm_studio.engine.design import load_preset

    calibration = calibrate(radiometry, load_preset("lfm_10x_na03"), dark=dark)
    save_calibration(calibration, "calib.json")
    image = rectify_frame(raw, load_calibration("calib.json"))   # (ny * 19, nx * 19)
"""

from lfm_studio.engine.calibration.calibration_io import (
    CalibrationFileError,
    calibration_files,
    calibration_from_dict,
    calibration_to_dict,
    load_calibration,
    save_calibration,
)
from lfm_studio.engine.calibration.fitted_design import fitted_design, nominal_design, rectified_design
from lfm_studio.engine.calibration.grid_fit import LatticeFit
from lfm_studio.engine.calibration.grid_fourier import NoGridError
from lfm_studio.engine.calibration.lattice import LensletLattice
from lfm_studio.engine.calibration.overlay import GridOverlay, grid_overlay
from lfm_studio.engine.calibration.pipeline import (
    FrameRectifier,
    calibrate,
    correct_frame,
    frame_rectifier,
    rectified_shape_fix,
    rectify_frame,
)
from lfm_studio.engine.calibration.record import CALIBRATION_VERSION, Calibration
from lfm_studio.engine.calibration.sub_images import SubImageFit

__all__ = [
    "CALIBRATION_VERSION",
    "Calibration",
    "CalibrationFileError",
    "FrameRectifier",
    "GridOverlay",
    "LatticeFit",
    "LensletLattice",
    "NoGridError",
    "SubImageFit",
    "calibrate",
    "calibration_files",
    "calibration_from_dict",
    "calibration_to_dict",
    "correct_frame",
    "fitted_design",
    "frame_rectifier",
    "grid_overlay",
    "load_calibration",
    "nominal_design",
    "rectified_design",
    "rectified_shape_fix",
    "rectify_frame",
    "save_calibration",
]
