"""The napari reader on damaged files of ours: an error notification naming the file, and no layer."""

from __future__ import annotations

import torch

from lfm_studio.engine.io import write_image
from lfm_studio.napari_plugin.reader import NOTHING, get_reader


def _ours(tmp_path):
    path = tmp_path / "lf.tif"
    write_image(path, torch.rand(256, 256), pixel_size=6.5e-6, metadata={"units": "ADU"})
    return path


def test_truncated_tiff_of_ours_is_named_and_adds_nothing(tmp_path, notes):
    path = _ours(tmp_path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])  # an interrupted copy: header intact, data cut
    reader = get_reader(str(path))
    assert reader is not None  # still recognised as ours from its header
    assert reader(str(path)) == NOTHING
    (message,) = notes.errors()
    assert "lf.tif" in message and "truncated or corrupt" in message and "Fix:" in message
