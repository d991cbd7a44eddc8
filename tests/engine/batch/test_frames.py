"""Frame sources: a multi-page TIFF, a folder of TIFFs and Zarr/OME-Zarr arrays read the same frames."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile
import zarr

from lfm_studio.engine.batch import open_frames

FRAMES = np.random.default_rng(0).integers(0, 4000, size=(7, 12, 10)).astype(np.uint16)


@pytest.fixture(params=["tiff", "tiff-folder", "zarr", "ome-zarr"])
def source(request, tmp_path):
    kind = request.param
    if kind == "tiff":
        tifffile.imwrite(tmp_path / "v.tif", FRAMES)
        return open_frames(tmp_path / "v.tif")
    if kind == "tiff-folder":
        for t, frame in enumerate(FRAMES):
            tifffile.imwrite(tmp_path / f"frame_{t:03d}.tif", frame)
        (tmp_path / "notes.txt").write_text("not a frame")
        return open_frames(tmp_path)
    array = zarr.create_array(
        str(tmp_path / "v.zarr"), shape=FRAMES.shape, chunks=(2, 12, 10), dtype="uint16"
    )
    array[:] = FRAMES
    if kind == "zarr":
        return open_frames(tmp_path / "v.zarr")
    group = zarr.open_group(str(tmp_path / "g.zarr"), mode="w", zarr_format=3)
    group.create_array("0", shape=FRAMES.shape, dtype="uint16")[:] = FRAMES
    group.attrs["ome"] = {"version": "0.5", "multiscales": [{"datasets": [{"path": "0"}]}]}
    return open_frames(tmp_path / "g.zarr")


def test_every_source_reads_the_same_frames(source):
    assert source.shape == FRAMES.shape and source.count == 7
    assert np.array_equal(source.read(2, 5), FRAMES[2:5])
    assert np.array_equal(source.read(6, 7), FRAMES[6:7])
    assert np.array_equal(source.to_dask().compute(), FRAMES)
    with pytest.raises(ValueError, match="outside 0:7"):
        source.read(5, 9)


def test_a_rewritten_tiff_is_read_afresh(tmp_path):
    path = tmp_path / "v.tif"
    tifffile.imwrite(path, FRAMES)
    assert np.array_equal(open_frames(path).read(0, 1), FRAMES[:1])
    tifffile.imwrite(path, FRAMES[::-1])
    assert np.array_equal(open_frames(path).read(0, 1), FRAMES[-1:])


def test_unreadable_sources_are_refused_by_name(tmp_path):
    with pytest.raises(FileNotFoundError, match="do not exist"):
        open_frames(tmp_path / "missing.tif")
    tifffile.imwrite(tmp_path / "v4.tif", np.zeros((2, 3, 4, 5), np.uint16), photometric="minisblack")
    with pytest.raises(ValueError, match=r"\(T, Y, X\)"):
        open_frames(tmp_path / "v4.tif")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match=r"no \.tif"):
        open_frames(tmp_path / "empty")
    zarr.open_group(str(tmp_path / "plain.zarr"), mode="w", zarr_format=3)
    with pytest.raises(ValueError, match="without OME 'multiscales'"):
        open_frames(tmp_path / "plain.zarr")
    group = zarr.open_group(str(tmp_path / "nopath.zarr"), mode="w", zarr_format=3)
    group.attrs["ome"] = {"version": "0.5", "multiscales": [{"datasets": []}]}
    with pytest.raises(ValueError, match="names no dataset path"):
        open_frames(tmp_path / "nopath.zarr")


@pytest.mark.parametrize("kind", ["tiff", "zarr", "tiff-folder"])
def test_one_2d_frame_reads_as_a_one_frame_video(tmp_path, kind):
    frame = FRAMES[3]  # (Y, X): a single camera image, not a (1, Y, X) stack
    if kind == "tiff":
        tifffile.imwrite(tmp_path / "one.tif", frame, photometric="minisblack")
        path = tmp_path / "one.tif"
    elif kind == "zarr":
        path = tmp_path / "one.zarr"
        zarr.create_array(str(path), shape=frame.shape, chunks=(4, 10), dtype="uint16")[:] = frame
    else:
        path = tmp_path / "folder"
        path.mkdir()
        tifffile.imwrite(path / "frame_000.tif", frame)
    source = open_frames(path)
    assert source.shape == (1, *frame.shape) and source.count == 1
    assert np.array_equal(source.read(0, 1), frame[None])
    assert np.array_equal(source.to_dask().compute(), frame[None])
