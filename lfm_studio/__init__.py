"""lfm_studio: a design studio for light-field microscopes.

The headless engine lives in :mod:`lfm_studio.engine`; the Qt studio in
:mod:`lfm_studio.ui` and :mod:`lfm_studio.widgets`.
"""

__version__ = "0.1.0"
