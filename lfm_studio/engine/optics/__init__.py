"""Scalar wave optics in torch: fields, propagation, lenses, MLA, objective, camera.

Each optical idea is a pure function ``Field -> Field``; SI units throughout.
"""

from lfm_studio.engine.optics.camera import Camera, integrate_pixels, simulate_sensor
from lfm_studio.engine.optics.debye import debye_psf
from lfm_studio.engine.optics.field import Field
from lfm_studio.engine.optics.grid import Grid
from lfm_studio.engine.optics.lenses import fourier_lens, thin_lens
from lfm_studio.engine.optics.mla import apply_mla, mla_transmission
from lfm_studio.engine.optics.mla_generators import hex_grid, square_grid
from lfm_studio.engine.optics.mla_layout import Lenslet, MicrolensArray
from lfm_studio.engine.optics.objective import ObjectiveLens
from lfm_studio.engine.optics.phase_mask import PhaseMask, apply_phase
from lfm_studio.engine.optics.propagation import choose_method, propagate
from lfm_studio.engine.optics.pupil_field import pupil_field
from lfm_studio.engine.optics.pupils import apply_pupil, circular_pupil, square_pupil
from lfm_studio.engine.optics.sources import gaussian_beam, plane_wave, point_source

__all__ = [
    "Camera",
    "Field",
    "Grid",
    "Lenslet",
    "MicrolensArray",
    "ObjectiveLens",
    "PhaseMask",
    "apply_mla",
    "apply_phase",
    "apply_pupil",
    "choose_method",
    "circular_pupil",
    "debye_psf",
    "fourier_lens",
    "gaussian_beam",
    "hex_grid",
    "integrate_pixels",
    "mla_transmission",
    "plane_wave",
    "point_source",
    "propagate",
    "pupil_field",
    "simulate_sensor",
    "square_grid",
    "square_pupil",
    "thin_lens",
]
