"""A truncated TIFF is refused with our error alone: tifffile's own warnings about it are not printed."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import tifffile

from lfm_studio.engine.io.file_checks import InputFileError
from lfm_studio.engine.io.hyperstack import read_hyperstack


def _imagej_stack(path, planes=6):
    data = np.arange(planes * 64 * 64, dtype=np.float32).reshape(planes, 64, 64)
    tifffile.imwrite(path, data, imagej=True)
    return data


def test_truncated_imagej_stack_is_refused_without_tifffile_log_lines(tmp_path, caplog):
    whole = tmp_path / "whole.tif"
    _imagej_stack(whole)
    short = tmp_path / "short.tif"
    short.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    with caplog.at_level(logging.DEBUG, logger="tifffile"), pytest.raises(InputFileError, match="truncated"):
        read_hyperstack(short)
    assert [r for r in caplog.records if r.name.startswith("tifffile")] == []
    assert logging.getLogger("tifffile").propagate  # left as it was


def test_a_good_file_reads_and_leaves_the_tifffile_logger_as_it_was(tmp_path):
    path = tmp_path / "good.tif"
    data = _imagej_stack(path, planes=3)
    logger = logging.getLogger("tifffile")
    handlers = list(logger.handlers)
    raw = read_hyperstack(path)
    assert np.array_equal(raw.array, data)  # a file round trip: the same bytes
    assert logger.handlers == handlers and logger.propagate
