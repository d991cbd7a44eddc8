"""Bundled data (preset designs, icons), installed as ``lfm_studio.resources``."""
