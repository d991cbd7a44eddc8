"""Stand-in widgets with the MLAEditor and PSFViewer contracts, for window tests.

They record what the studio asks of them, so controller and window tests do not need
napari or the real editor (and run even before those widgets exist).
"""

from __future__ import annotations

from qtpy.QtCore import Signal
from qtpy.QtWidgets import QLabel, QWidget


class FakeMLAEditor(QLabel):
    """The MLAEditor contract: set_lenslets / lenslets / set_pupil_radius / set_sensor / set_summary and
    two signals."""

    lensletsCommitted = Signal(object)  # noqa: N815 (the MLAEditor contract)
    lensletsPreview = Signal(object)  # noqa: N815

    def __init__(self, lenslets=(), *, pupil_radius_um=None, sensor_size_um=None, parent=None):
        super().__init__("MLA editor stand-in", parent)
        self._lenslets = tuple(lenslets)
        self.pupil_radius_um = pupil_radius_um
        self.sensor = (sensor_size_um, None, None)
        self.set_lenslets_calls = 0

    def set_lenslets(self, lenslets):
        self.blockSignals(True)
        self._lenslets = tuple(lenslets)
        self.set_lenslets_calls += 1
        self.blockSignals(False)

    def lenslets(self):
        return self._lenslets

    def set_pupil_radius(self, um):
        self.pupil_radius_um = um

    def set_sensor(self, size_um, sub_image_radius_um, magnification=None):
        self.sensor = (size_um, sub_image_radius_um, magnification)

    def set_summary(self, text):
        self.summary = text

    def commit(self, lenslets):
        """What a user edit does: the new list, then the commit signal."""
        self._lenslets = tuple(lenslets)
        self.lensletsCommitted.emit(self._lenslets)

    def undo(self):
        pass

    def redo(self):
        pass

    def can_undo(self):
        return False

    def can_redo(self):
        return False

    def selected_indices(self):
        return []


class FakePSFViewer(QWidget):
    """The PSFViewer contract; records every call as (method, name, shape)."""

    def __init__(self, parent=None, *, use_napari=None):
        super().__init__(parent)
        self.calls: list[tuple[str, str, tuple[int, ...]]] = []
        self.closed = False
        self.stale_marks: dict[str, str] = {}  # layer -> the text of its stale mark

    def set_stale_marks(self, marks):
        self.stale_marks = {layer: mark.text for layer, mark in marks.items()}

    @property
    def backend(self):
        return "pyqtgraph"

    def show_psf(self, stack):
        self.calls.append(("show_psf", "PSF", tuple(stack.data.shape)))

    def show_image(self, image, pixel_size_m, name="light field"):
        self.calls.append(("show_image", name, tuple(image.shape)))

    def show_volume(self, volume, voxel_size_m, name="reconstruction"):
        self.calls.append(("show_volume", name, tuple(volume.shape)))

    def clear(self):
        self.calls.append(("clear", "", ()))

    def set_3d(self, on):
        pass

    def layer_names(self):
        return [name for _, name, _ in self.calls]

    def close_viewer(self):
        self.closed = True


def small_fourier_design():
    """A small Fourier LFM for fast UI tests: the FLFM preset's optics, 4 separated lenslets, 256^2 px, 3 depths.

    The preset's own square 600 um lenslets touch, so their light footprints on the sensor
    overlap and the engine falls back to the full-field method (no per-lenslet cache);
    these 800 um circles 1200 um apart keep the per-lenslet path, preview accuracy keeps it
    under a second.
    """
    from lfm_studio.engine.design import DepthSpec, LensletSpec, MLASpec, load_preset

    base = load_preset("flfm_guo2019")
    lenslets = [
        LensletSpec(center_um=(x, y), aperture_diameter_um=800.0, focal_length_mm=16.8)
        for y in (-600.0, 600.0)
        for x in (-600.0, 600.0)
    ]
    camera = {**base.camera.model_dump(), "pixel_count": (256, 256)}
    return base.updated(
        name="small FLFM test design",
        camera=camera,
        depths=DepthSpec(depth_range_um=(-10.0, 10.0), depth_step_um=10.0),
        relay={"focal_length_mm": 75.0, "field_stop_diameter_mm": 2.0},
        mla=MLASpec(lenslets=tuple(lenslets)),
        accuracy={"preset": "preview"},
    )


def small_conventional_design():
    """A small conventional LFM for fast UI tests: the 10x/0.3 preset on 128^2 px behind 8 x 8 lenslets,
    17 depths 5 um apart (its 5-depth preview: 20 um apart), preview accuracy (about a second)."""
    from lfm_studio.engine.design import DepthSpec, load_preset

    base = load_preset("lfm_10x_na03")
    return base.updated(
        name="small conventional LFM test design",
        camera={**base.camera.model_dump(), "pixel_count": (128, 128)},
        mla={**base.mla.model_dump(), "shape": (8, 8)},
        depths=DepthSpec(depth_range_um=(-40.0, 40.0), depth_step_um=5.0),
        accuracy={"preset": "preview"},
    )
