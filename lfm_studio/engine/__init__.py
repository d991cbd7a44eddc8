"""Headless simulation engine: optics, forward models, reconstruction.

Never imports Qt, napari or plotting libraries (checked by import-linter and a test).
Engine internals use SI units: metres, radians, seconds.
"""

from lfm_studio.engine import units
from lfm_studio.engine.errors import SamplingError, SamplingWarning

__all__ = ["SamplingError", "SamplingWarning", "units"]
