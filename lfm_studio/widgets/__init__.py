"""Reusable Qt widgets (MLA layout editor, PSF viewer), importable inside napari."""
