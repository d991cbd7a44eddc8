"""The OME-Zarr output: NGFF 0.5 metadata with physical scales read back by ome-zarr, our napari
reader and a napari layer; the run record (design, method, options, version) round-trips."""

from __future__ import annotations

import json

import dask.array as da
import numpy as np
import pytest
import zarr
from ome_zarr.io import parse_url
from ome_zarr.reader import Reader

from lfm_studio import __version__
from lfm_studio.engine.batch import reconstruct_video
from lfm_studio.engine.design import design_from_json, optics_hash
from lfm_studio.engine.threads import torch_threads
from lfm_studio.napari_plugin.zarr_reader import get_zarr_reader
from tests.engine.batch.conftest import CROP, ITERATIONS, METHOD

UM = 1e-6


@pytest.fixture(scope="module")
def store(video, tmp_path_factory):
    out = tmp_path_factory.mktemp("ome") / "run.ome.zarr"
    with torch_threads(1):  # as the reference (module fixtures run outside conftest's one_thread)
        reconstruct_video(
            video.tiff, video.design, method=METHOD, iterations=ITERATIONS, crop=CROP, output=out,
            chunk_frames=4, frame_interval_s=0.5,
        )  # fmt: skip
    return out


def _expected_scale(video, level: int) -> list[float]:
    _, dy, dx = video.voxel_size
    return [0.5, 20.0, dy / UM * 2**level, dx / UM * 2**level]  # 0.5 s frames, depths 20 um apart


def test_ome_zarr_reads_axes_and_scales(video, store):
    node = next(iter(Reader(parse_url(str(store)))()))
    assert [a["name"] for a in node.metadata["axes"]] == ["t", "z", "y", "x"]
    assert [a.get("unit") for a in node.metadata["axes"]] == [
        "second",
        "micrometer",
        "micrometer",
        "micrometer",
    ]
    assert len(node.data) >= 2 and node.data[1].shape[-2:] == tuple(n // 2 for n in node.data[0].shape[-2:])
    for level, transforms in enumerate(node.metadata["coordinateTransformations"][:2]):
        scale = next(t["scale"] for t in transforms if t["type"] == "scale")
        np.testing.assert_allclose(scale, _expected_scale(video, level), rtol=1e-12)
    translation = next(
        t["translation"] for t in node.metadata["coordinateTransformations"][0] if t["type"] == "translation"
    )
    ny = node.data[0].shape[-2]
    np.testing.assert_allclose(
        translation,
        [0.0, -20.0, -(ny // 2) * video.voxel_size[1] / UM, -(ny // 2) * video.voxel_size[2] / UM],
    )
    group = zarr.open_group(str(store), mode="r")
    assert group.metadata.zarr_format == 3 and dict(group.attrs)["ome"]["version"] == "0.5"


def test_run_record_round_trips(video, store):
    record = dict(zarr.open_group(str(store), mode="r").attrs)["lfm_studio"]
    assert record["version"] == __version__ and record["method"] == METHOD
    assert record["options"]["iterations"] == ITERATIONS and record["frame_interval_assumed"] is False
    design = design_from_json(json.dumps(record["design"]))
    assert optics_hash(design) == optics_hash(video.design)
    np.testing.assert_allclose(record["depths_um"], [-20.0, 0.0, 20.0], atol=1e-9)


def test_napari_reader_opens_the_store_lazily_with_scales(video, store):
    reader = get_zarr_reader(str(store))
    assert reader is not None and get_zarr_reader(str(video.tiff)) is None
    [(levels, meta, kind)] = reader(str(store))
    assert kind == "image" and meta["multiscale"] and all(isinstance(level, da.Array) for level in levels)
    np.testing.assert_allclose(meta["scale"], _expected_scale(video, 0), rtol=1e-12)
    assert meta["axis_labels"] == ("t", "z", "y", "x") and meta["units"] == ("s", "um", "um", "um")
    assert np.array_equal(levels[0][2].compute(), video.reference[2])
    napari = pytest.importorskip("napari")
    from npe2 import PluginManager

    PluginManager.instance().discover()  # a bare ViewerModel does not (docs/platform.md)
    [layer] = napari.components.ViewerModel().open(str(store), plugin="lfm-studio")  # the manifest entry
    np.testing.assert_allclose(layer.scale, _expected_scale(video, 0), rtol=1e-12)
    assert layer.multiscale and layer.metadata["lfm_studio"]["method"] == METHOD
    assert layer.data[0].shape == video.reference.shape


def test_frames_without_a_reconstruction_are_named_by_the_reader(video, store, tmp_path):
    """A failed frame and a chunk not computed yet hold zeros: the report, the layer name and its
    metadata say which, so a zero volume is not read as an empty sample."""
    import shutil

    from lfm_studio.engine.batch.store import frame_report
    from lfm_studio.napari_plugin.zarr_reader import ome_zarr_layers

    copy = tmp_path / "run.ome.zarr"
    shutil.copytree(store, copy)
    assert frame_report(copy).failed == {} and frame_report(copy).missing == ()
    assert frame_report(copy).summary() is None
    status = copy / "lfm_studio_status"
    first = json.loads((status / "chunk_000000.json").read_text())
    first["frames"]["1"] = {
        "status": "failed",
        "attempts": 2,
        "error": "ValueError: frame 1 has 3 NaN pixel(s)",
    }
    (status / "chunk_000000.json").write_text(json.dumps(first))
    (status / "chunk_000001.json").unlink()  # as if the run was cancelled before its second chunk
    report = frame_report(copy)
    assert report.failed == {1: "ValueError: frame 1 has 3 NaN pixel(s)"} and report.missing == (4, 5, 6, 7)
    assert report.summary() == (
        "frame(s) 1 failed; frame(s) 4, 5, 6, 7 not computed yet (resume the run to finish them): their "
        "volumes are zeros, not data."
    )
    [(_, meta, _)] = ome_zarr_layers(copy, warn=False)
    assert meta["name"].endswith("(1 failed, 4 not computed)")
    assert meta["metadata"]["failed_frames"] == report.failed and meta["metadata"]["missing_frames"] == [
        4,
        5,
        6,
        7,
    ]
    [(_, complete, _)] = ome_zarr_layers(store, warn=False)
    assert "failed_frames" not in complete["metadata"] and "(" not in complete["name"]
