"""TIFF round trips, ImageJ hyperstack scale, overwrite safety and foreign files.

Tolerances: data stored as float32 must come back bit-identical (no arithmetic on
it); SI lengths and depth lists come back bit-identical too (the header writes exact
decimal shifts, see metadata.py). Only the ImageJ X/YResolution is a TIFF rational,
so the scale Fiji reads is checked to 1e-6 relative (tifffile's rational has >= 7
significant digits).
"""

from __future__ import annotations

import json
import os
import sys
import types

import numpy as np
import pytest
import tifffile
import torch

from lfm_studio.engine.io import (
    HeaderError,
    LightFieldImage,
    MissingMetadataError,
    OutputError,
    Volume,
    read_image,
    read_psf_stack,
    read_volume,
    write_image,
    write_psf_stack,
    write_volume,
)
from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.engine.units import nm, um

RATIONAL_RTOL = 1e-6  # TIFF X/YResolution is a ratio of 32-bit integers
# Comparisons of SI lengths pass abs=0: pytest.approx's default abs=1e-12 would swamp metres.


def _stack(shape=(5, 12, 10), *, dtype=torch.float32, design=None, seed=0) -> PSFStack:
    g = torch.Generator().manual_seed(seed)
    data = torch.rand(shape, generator=g, dtype=dtype)
    depths = (-30 * um, -12.5 * um, 0.0, 7.3 * um, 41 * um)[: shape[-3]]  # non-uniform on purpose
    return PSFStack(
        data, depths, pixel_size=6.5 * um, magnification=20 / 1.3, wavelength=525 * nm, design=design,
        metadata={"source": "unit test", "beads": [1, 2, 3], "nested": {"a": 0.1}},
    )  # fmt: skip


# -- round trips ------------------------------------------------------------------------


def test_psf_stack_round_trip_is_exact(tmp_path):
    stack = _stack(design={"kind": "fourier", "pitch_um": 1300.0})
    path = write_psf_stack(tmp_path / "psf.tif", stack)
    back = read_psf_stack(path)
    assert torch.equal(back.data, stack.data)  # float32 stored as float32: bit-identical
    assert back.depths == stack.depths  # exact, non-uniform
    assert back.pixel_size == stack.pixel_size
    assert back.magnification == stack.magnification
    assert back.wavelength == stack.wavelength
    assert back.metadata == stack.metadata
    assert back.design == stack.design  # saved from a dict: comes back as that dict


def test_psf_stack_batch_dims_and_float64(tmp_path):
    stack = _stack((2, 3, 4, 6, 5), dtype=torch.float64)
    back = read_psf_stack(write_psf_stack(tmp_path / "psf.tif", stack), dtype=torch.float64)
    assert back.data.shape == stack.data.shape
    assert back.data.dtype == torch.float64
    # float64 is stored as float32 (ImageJ has no float64): equal to the float32 cast exactly.
    assert torch.equal(back.data, stack.data.float().double())
    with tifffile.TiffFile(tmp_path / "psf.tif") as tif:
        header = json.loads(tif.imagej_metadata["Info"])
        assert tif.series[0].axes == "TZYX" and tif.series[0].shape == (6, 4, 6, 5)
    assert header["source_dtype"] == "float64" and header["shape"] == [2, 3, 4, 6, 5]


def test_unit_values_round_trip_bit_exact(tmp_path):
    # Values where z * 1e6 / 1e6 != z (multiplying then dividing by 1e6 loses 1 ulp).
    depths = tuple(float(v) for v in torch.linspace(-57.3, 61.9, 23, dtype=torch.float64) * um)
    assert any(z * 1e6 / 1e6 != z for z in depths)
    stack = PSFStack(
        torch.zeros(23, 2, 2), depths, 3.4500000000000003 * um, 1.0 / 3.0, 488.00000000000006 * nm
    )
    back = read_psf_stack(write_psf_stack(tmp_path / "psf.tif", stack))
    assert back.depths == depths
    assert (back.pixel_size, back.magnification, back.wavelength) == (
        stack.pixel_size,
        stack.magnification,
        stack.wavelength,
    )


def test_volume_round_trip(tmp_path):
    data = torch.rand(4, 6, 7, generator=torch.Generator().manual_seed(1))
    depths = (-3 * um, 0.0, 2 * um, 10 * um)
    path = write_volume(tmp_path / "v.tif", data, voxel_size=(2.5 * um, 0.65 * um, 0.65 * um), depths=depths,
                        metadata={"phantom": "beads", "seed": 3})  # fmt: skip
    back = read_volume(path)
    assert isinstance(back, Volume)
    assert torch.equal(back.data, data)
    assert back.voxel_size == (2.5 * um, 0.65 * um, 0.65 * um)
    assert back.depths == depths
    assert back.metadata == {"phantom": "beads", "seed": 3}


def test_volume_time_series_without_depths(tmp_path):
    data = torch.rand(3, 2, 5, 4, generator=torch.Generator().manual_seed(2))
    vol = Volume(data, (1 * um, 0.5 * um, 0.25 * um))
    back = read_volume(write_volume(tmp_path / "t.tif", vol))
    assert torch.equal(back.data, data)
    assert back.depths is None and back.voxel_size == vol.voxel_size
    assert back.depth_values() == (-1 * um, 0.0)


def test_image_round_trip_float_and_uint16(tmp_path):
    frames = torch.rand(3, 8, 9, generator=torch.Generator().manual_seed(3))
    back = read_image(
        write_image(tmp_path / "lf.tif", frames, pixel_size=6.5 * um, metadata={"exposure_ms": 20})
    )
    assert isinstance(back, LightFieldImage)
    assert torch.equal(back.data, frames) and back.pixel_size == 6.5 * um
    assert back.metadata == {"exposure_ms": 20}
    counts = np.arange(8 * 9, dtype=np.uint16).reshape(8, 9) * 900  # up to 63900: uint16 range
    write_image(tmp_path / "raw.tif", torch.from_numpy(counts.astype(np.int32)), pixel_size=6.5 * um)
    with tifffile.TiffFile(tmp_path / "raw.tif") as tif:
        assert tif.series[0].dtype == np.float32  # int32 -> float32 (exact below 2**24)
    assert torch.equal(read_image(tmp_path / "raw.tif").data, torch.from_numpy(counts.astype(np.float32)))
    write_image(tmp_path / "u16.tif", counts, pixel_size=6.5 * um)  # numpy uint16 kept as uint16
    with tifffile.TiffFile(tmp_path / "u16.tif") as tif:
        assert tif.series[0].dtype == np.uint16


# -- what Fiji and napari see ------------------------------------------------------------


def test_psf_file_is_imagej_hyperstack_with_physical_scale(tmp_path):
    stack = _stack()
    path = write_psf_stack(tmp_path / "psf.tif", stack)
    with tifffile.TiffFile(path) as tif:
        assert tif.is_imagej
        meta = tif.imagej_metadata
        assert tif.series[0].axes == "ZYX"
        assert meta["slices"] == 5 and meta["hyperstack"] is True
        assert meta["unit"] == "um"
        # spacing: mean depth step (exact depths are in Info and in the slice labels)
        assert meta["spacing"] == pytest.approx((41 + 30) / 4, rel=1e-12)
        assert meta["Labels"][0] == "z=-30 um" and meta["Labels"][3] == "z=7.3 um"
        # lateral scale: sample-side pixel = 6.5 um / (20 / 1.3) = 0.4225 um
        xres, yres = tif.pages.first.resolution
        pixel_x_um, pixel_y_um = 1 / xres, 1 / yres
        assert pixel_x_um == pytest.approx(0.4225, rel=RATIONAL_RTOL)
        assert pixel_y_um == pytest.approx(0.4225, rel=RATIONAL_RTOL)
        assert tif.pages.first.dtype == np.float32
        info = json.loads(meta["Info"])
    assert info["format"] == "lfm_studio" and info["kind"] == "psf_stack" and info["schema_version"] == 1
    assert info["pixel_size_um"] == 6.5 and info["wavelength_nm"] == 525.0000000000001


def test_volume_file_scale(tmp_path):
    path = write_volume(tmp_path / "v.tif", torch.zeros(2, 3, 3, 4), voxel_size=(4 * um, 0.5 * um, 0.25 * um))
    with tifffile.TiffFile(path) as tif:
        meta = tif.imagej_metadata
        assert tif.series[0].axes == "TZYX"
        assert (meta["frames"], meta["slices"], meta["spacing"], meta["unit"]) == (2, 3, 4.0, "um")
        xres, yres = tif.pages.first.resolution
        assert (1 / xres, 1 / yres) == pytest.approx((0.25, 0.5), rel=RATIONAL_RTOL)


# -- refusing bad data -------------------------------------------------------------------


def test_complex_and_nonfinite_data_are_refused(tmp_path):
    with pytest.raises(TypeError, match="complex"):
        write_volume(tmp_path / "c.tif", torch.zeros(2, 3, 3, dtype=torch.complex64), voxel_size=(1e-6,) * 3)
    bad = torch.zeros(2, 3, 3)
    bad[0, 1, 1] = float("nan")
    with pytest.raises(ValueError, match="NaN/Inf"):
        write_volume(tmp_path / "n.tif", bad, voxel_size=(1e-6,) * 3)
    with pytest.raises(ValueError, match="float32 range"):
        write_image(tmp_path / "big.tif", torch.full((2, 2), 1e300, dtype=torch.float64), pixel_size=1e-6)
    with pytest.raises(TypeError, match="voxel_size"):
        write_volume(tmp_path / "v.tif", torch.zeros(2, 3, 3))
    with pytest.raises(ValueError, match="voxel_size dz must be a finite number > 0"):
        write_volume(tmp_path / "v.tif", torch.zeros(2, 3, 3), voxel_size=(0.0, 1e-6, 1e-6))
    with pytest.raises(ValueError, match="2 slices but 3 depths"):
        write_volume(tmp_path / "v.tif", torch.zeros(2, 3, 3), voxel_size=(1e-6,) * 3, depths=(0, 1e-6, 2e-6))
    assert not list(tmp_path.iterdir())  # nothing written, no temp files


def test_sizes_in_micrometres_passed_as_metres_are_refused(tmp_path):
    with pytest.raises(
        ValueError,
        match=r"voxel_size must be in metres, below 1 mm; got \(10, 0\.7, 0\.7\) m, and a 10 m sample is no "
        r"microscope's\. Nothing was written\. Fix: did you pass um\? "
        r"Use voxel_size=\(10 \* um, 0\.7 \* um, 0\.7 \* um\)",
    ):
        write_volume(tmp_path / "v.tif", torch.ones(2, 3, 3), voxel_size=(10.0, 0.7, 0.7))
    with pytest.raises(ValueError, match=r"pixel_size must be in metres.*Use pixel_size=\(6\.5 \* um\)"):
        write_image(tmp_path / "i.tif", torch.ones(3, 3), pixel_size=6.5)
    assert not list(tmp_path.iterdir())
    write_volume(
        tmp_path / "v.tif", torch.ones(2, 3, 3), voxel_size=(500 * um, 0.7 * um, 0.7 * um)
    )  # coarse, real


def test_a_tiff_under_another_name_and_an_empty_volume_are_refused(tmp_path):
    with pytest.raises(
        OutputError, match=r"v\.png would hold a TIFF, .*Nothing was written\. Fix: name it v\.tif\."
    ):
        write_volume(tmp_path / "v.png", torch.ones(2, 3, 3), voxel_size=(1e-6,) * 3)
    with pytest.raises(OutputError, match=r"Fix: name it psf\.tif\."):
        write_psf_stack(tmp_path / "psf", _stack())
    with pytest.raises(
        ValueError, match=r"volume is empty \(shape \(0, 5, 5\)\): a TIFF holds at least one pixel"
    ):
        write_volume(tmp_path / "v.tif", torch.zeros(0, 5, 5), voxel_size=(1e-6,) * 3)
    assert not list(tmp_path.iterdir())
    assert write_image(tmp_path / "i.TIFF", torch.ones(3, 3), pixel_size=6.5 * um).is_file()


# -- overwrite protection and atomicity ----------------------------------------------------


def test_existing_file_is_not_overwritten_unless_asked(tmp_path):
    path = tmp_path / "v.tif"
    write_volume(path, torch.ones(1, 2, 2), voxel_size=(1e-6,) * 3)
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match=r"v.tif already exists.*overwrite=True"):
        write_volume(path, torch.zeros(1, 2, 2), voxel_size=(1e-6,) * 3)
    assert path.read_bytes() == before
    write_volume(path, torch.zeros(1, 2, 2), voxel_size=(1e-6,) * 3, overwrite=True)
    assert torch.equal(read_volume(path).data, torch.zeros(1, 2, 2))


def test_failed_replace_keeps_old_file_and_leaves_no_temp(tmp_path, monkeypatch):
    path = tmp_path / "psf.tif"
    write_psf_stack(path, _stack())
    before = path.read_bytes()

    def broken_replace(src, dst):
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(os, "replace", broken_replace)
    # an OSError while writing becomes a named OutputError (exit 3 in the CLI); nothing is left behind
    with pytest.raises(OutputError, match=r"cannot write .*psf\.tif: disk full \(simulated\)"):
        write_psf_stack(path, _stack(seed=1), overwrite=True)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["psf.tif"]


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    def broken_imwrite(*args, **kwargs):
        raise RuntimeError("encoder crashed (simulated)")

    monkeypatch.setattr(tifffile, "imwrite", broken_imwrite)
    with pytest.raises(RuntimeError, match="simulated"):
        write_image(tmp_path / "lf.tif", torch.zeros(4, 4), pixel_size=1e-6)
    assert list(tmp_path.iterdir()) == []


# -- files written by other tools ----------------------------------------------------------


@pytest.mark.parametrize("nz", [4, 7])
@pytest.mark.filterwarnings("ignore::DeprecationWarning:tifffile")
def test_foreign_tiff_without_metadata_names_what_is_missing(tmp_path, nz):
    # A plain tifffile.imwrite: (7, Y, X) is stored as 7 pages, (4, Y, X) as a planar
    # RGBA image (tifffile's legacy default): both must read as a stack.
    data = np.random.default_rng(0).random((nz, 5, 6)).astype(np.float32)
    tifffile.imwrite(tmp_path / "bead.tif", data)
    with pytest.raises(
        MissingMetadataError, match=r"bead.tif has no voxel size dz, dy, dx.*voxel_size="
    ) as err:
        read_volume(tmp_path / "bead.tif")
    assert err.value.missing == ("voxel_size",)
    vol = read_volume(tmp_path / "bead.tif", voxel_size=(2 * um, 0.5 * um, 0.5 * um))
    assert np.array_equal(vol.data.numpy(), data) and vol.voxel_size == (2 * um, 0.5 * um, 0.5 * um)

    with pytest.raises(MissingMetadataError, match="pixel_size, magnification, wavelength, depths") as err:
        read_psf_stack(tmp_path / "bead.tif")
    assert err.value.missing == ("pixel_size", "magnification", "wavelength", "depths")
    stack = read_psf_stack(tmp_path / "bead.tif", pixel_size=6.5 * um, magnification=10.0, wavelength=525 * nm,
                           depths=[(i - 2) * 2 * um for i in range(nz)])  # fmt: skip
    assert np.array_equal(stack.data.numpy(), data)

    tifffile.imwrite(tmp_path / "frame.tif", data[0])
    with pytest.raises(MissingMetadataError, match=r"frame.tif has no pixel_size.*pixel_size=6.5 \* um"):
        read_image(tmp_path / "frame.tif")
    assert read_image(tmp_path / "frame.tif", pixel_size=6.5 * um).pixel_size == 6.5 * um


def test_foreign_imagej_stack_uses_its_calibration(tmp_path):
    # As Fiji saves a calibrated bead stack: 0.325 um pixels, 2 um steps, no lfm_studio header.
    data = np.random.default_rng(1).random((3, 4, 5)).astype(np.float32)
    tifffile.imwrite(tmp_path / "fiji.tif", data, imagej=True, resolution=(1 / 0.325, 1 / 0.325),
                     metadata={"axes": "ZYX", "spacing": 2.0, "unit": "micron"})  # fmt: skip
    vol = read_volume(tmp_path / "fiji.tif")
    assert vol.voxel_size == pytest.approx((2 * um, 0.325 * um, 0.325 * um), rel=RATIONAL_RTOL, abs=0)
    assert read_volume(tmp_path / "fiji.tif", voxel_size=(5 * um, None, None)).voxel_size[0] == 5 * um
    # PSF: the calibration is sample-side, so only magnification (not pixel size) is missing.
    with pytest.raises(MissingMetadataError, match=r"magnification, wavelength, depths.*0.325 um pixels"):
        read_psf_stack(tmp_path / "fiji.tif")
    stack = read_psf_stack(
        tmp_path / "fiji.tif", magnification=20.0, wavelength=520 * nm, depths=[-2e-6, 0, 2e-6]
    )
    assert stack.pixel_size == pytest.approx(6.5 * um, rel=RATIONAL_RTOL, abs=0)
    assert stack.object_pixel_size == pytest.approx(0.325 * um, rel=RATIONAL_RTOL, abs=0)


def test_foreign_ome_tiff_physical_size(tmp_path):
    data = np.zeros((3, 4, 5), np.float32)
    tifffile.imwrite(tmp_path / "o.ome.tif", data, ome=True,
                     metadata={"axes": "ZYX", "PhysicalSizeX": 0.5, "PhysicalSizeY": 0.5, "PhysicalSizeZ": 1.5})  # fmt: skip
    assert read_volume(tmp_path / "o.ome.tif").voxel_size == (1.5 * um, 0.5 * um, 0.5 * um)


def test_foreign_rgb_is_refused(tmp_path):
    tifffile.imwrite(tmp_path / "rgb.tif", np.zeros((4, 5, 3), np.uint8), photometric="rgb")
    with pytest.raises(ValueError, match="colour samples"):
        read_image(tmp_path / "rgb.tif", pixel_size=1e-6)


# -- headers of the wrong kind or from the future ------------------------------------------


def test_wrong_kind_and_newer_schema(tmp_path):
    write_image(tmp_path / "lf.tif", torch.zeros(3, 3), pixel_size=1e-6)
    with pytest.raises(HeaderError, match=r"holds an lfm_studio 'image', not a 'volume'.*read_image"):
        read_volume(tmp_path / "lf.tif")
    info = json.dumps({"format": "lfm_studio", "kind": "image", "schema_version": 99, "shape": [3, 3]})
    tifffile.imwrite(tmp_path / "new.tif", np.zeros((3, 3), np.float32), imagej=True, metadata={"Info": info})
    with pytest.raises(HeaderError, match=r"schema 99.*update lfm_studio"):
        read_image(tmp_path / "new.tif")


def test_header_that_no_longer_matches_the_data(tmp_path):
    # As if Fiji cropped the stack and kept the Info property.
    info = json.dumps({"format": "lfm_studio", "kind": "volume", "schema_version": 1, "shape": [4, 3, 3],
                       "voxel_size_um": [1, 1, 1]})  # fmt: skip
    tifffile.imwrite(
        tmp_path / "crop.tif", np.zeros((2, 3, 3), np.float32), imagej=True, metadata={"Info": info}
    )
    with pytest.raises(HeaderError, match=r"no longer matches its lfm_studio header"):
        read_volume(tmp_path / "crop.tif")


# -- the design ----------------------------------------------------------------------------


class _FakeDesign:
    """Stands in for the pydantic Design (model_dump_json / design_from_json)."""

    def __init__(self, pitch_um: float):
        self.pitch_um = pitch_um

    def model_dump_json(self) -> str:
        return json.dumps({"schema_version": 1, "pitch_um": self.pitch_um})


def test_design_is_rebuilt_when_the_design_module_offers_it(tmp_path, monkeypatch):
    module = types.ModuleType("lfm_studio.engine.design")
    module.design_from_json = lambda text: _FakeDesign(json.loads(text)["pitch_um"])
    monkeypatch.setitem(sys.modules, "lfm_studio.engine.design", module)
    path = write_psf_stack(tmp_path / "psf.tif", _stack(design=_FakeDesign(150.0)))
    back = read_psf_stack(path)
    assert isinstance(back.design, _FakeDesign) and back.design.pitch_um == 150.0
    assert read_psf_stack(path, rebuild_design=False).design == {"schema_version": 1, "pitch_um": 150.0}

    def refuse(text):
        raise ValueError("unknown key")

    module.design_from_json = refuse
    with pytest.raises(HeaderError, match=r"design could not be rebuilt.*rebuild_design=False"):
        read_psf_stack(path)


def test_real_preset_design_round_trips(tmp_path):
    design_module = pytest.importorskip("lfm_studio.engine.design")
    if not hasattr(design_module, "load_preset"):
        pytest.skip("lfm_studio.engine.design has no presets yet")
    design = design_module.load_preset("lfm_10x_na03")
    back = read_psf_stack(write_psf_stack(tmp_path / "psf.tif", _stack(design=design)))
    assert type(back.design) is type(design) and back.design == design


def test_design_stays_json_without_design_module(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "lfm_studio.engine.design", None)  # import fails as if absent
    path = write_psf_stack(tmp_path / "psf.tif", _stack(design=_FakeDesign(125.0)))
    assert read_psf_stack(path).design == {"schema_version": 1, "pitch_um": 125.0}


def test_undumpable_design_and_metadata_are_refused(tmp_path):
    with pytest.raises(TypeError, match="Cannot store a design of type object"):
        write_psf_stack(tmp_path / "a.tif", _stack(design=object()))
    with pytest.raises(TypeError, match="JSON-serialisable"):
        write_volume(
            tmp_path / "b.tif", torch.zeros(1, 2, 2), voxel_size=(1e-6,) * 3, metadata={"t": torch.ones(1)}
        )
    assert list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_read_to_cuda(tmp_path):
    stack = _stack()
    back = read_psf_stack(write_psf_stack(tmp_path / "psf.tif", stack), device="cuda")
    assert back.data.is_cuda and torch.equal(back.data.cpu(), stack.data)
    write_volume(tmp_path / "v.tif", stack.data.cuda(), voxel_size=(1e-6,) * 3)  # CUDA tensors are accepted
    assert torch.equal(read_volume(tmp_path / "v.tif").data, stack.data)
