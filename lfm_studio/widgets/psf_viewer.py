"""``PSFViewer``: the PSF stack, the camera image and the reconstruction as layers in micrometres.

napari (embedded through :mod:`lfm_studio.widgets.napari_embed`) when OpenGL works, otherwise a
pyqtgraph fallback (:mod:`lfm_studio.widgets.pyqtgraph_volume`) with a message saying why.

Display conventions (also written into each layer's ``metadata``):

- PSF stacks and light-field images are in **sensor** micrometres: lateral pixel = the camera
  pixel pitch (camera side; the sample-side size is pitch / magnification), the optical axis
  at pixel ``N // 2``. The PSF's depth axis is the source depth in sample-side micrometres.
- Reconstructions are in **sample** micrometres (voxel size as given), centred on the
  optical axis unless an origin is given.
- A PSF spans millimetres on the sensor but only tens of micrometres in depth, so a
  display-only axial stretch (``z_stretch``, a 1-2-5 number) is applied through the layer's
  affine when the depth span is small; ``layer.scale`` stays the physical scale in um.
- The two spaces do not share a world: each has its own napari canvas, and showing a layer
  of the other space switches canvas (layers are kept and updated in place, never re-made).
- Volumes over ``max_voxels_3d`` (per displayed 3-D block) are rendered in 3-D from a
  laterally max-pooled preview; 2-D slices always show the full data.

All methods must be called on the GUI thread.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from qtpy.QtCore import QThread
from qtpy.QtWidgets import (
    QApplication,
    QComboBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.engine.psf_stack import PSFStack
from lfm_studio.widgets import napari_embed

#: Per displayed 3-D block: 2**24 float32 voxels = 64 MiB, about 0.45 s/frame in software GL.
DEFAULT_MAX_VOXELS_3D = 2**24
SENSOR, SAMPLE = "sensor", "sample"


@dataclass
class DisplayData:
    """One layer as shown: float32 data ``(..., Y, X)``, sampling in um, look and provenance."""

    name: str
    data: np.ndarray
    scale_um: tuple[float, ...]
    translate_um: tuple[float, ...]
    space: str
    axis_labels: tuple[str, ...]
    colormap: str
    contrast_limits: tuple[float, float] | None  # None: per-slice auto contrast
    z_stretch: float = 1.0  # display-only axial exaggeration (through the layer affine)
    has_depth: bool = True  # the third-last axis is depth
    initial_step: dict[int, int] = field(default_factory=dict)  # starting slider positions
    metadata: dict[str, Any] = field(default_factory=dict)

    @property
    def z_axis(self) -> int | None:
        """Index of the depth axis in ``data`` (``None`` for 2-D images)."""
        return self.data.ndim - 3 if self.has_depth else None


def psf_display(stack: PSFStack, name: str = "PSF") -> DisplayData:
    """A PSF stack (Fourier ``(Z, Y, X)`` or conventional ``(S, S, Z, H, H)``) for display."""
    data = _numpy(stack.data)
    depths = np.asarray(stack.depths, dtype=np.float64) * 1e6
    order = np.argsort(depths)
    if np.any(order != np.arange(depths.size)):
        data, depths = np.take(data, order, axis=-3), depths[order]
    dz, uniform = _depth_step(depths, stack.object_pixel_size * 1e6)
    px = stack.pixel_size * 1e6
    ny, nx = data.shape[-2:]
    lead = data.ndim - 3
    conventional = stack.metadata.get("kind") == "conventional" and lead == 2
    lead_labels = ("sub-position row", "sub-position column") if conventional else _axis_names(lead)
    z_span = dz * depths.size
    meta = {
        "kind": "psf",
        "model": "conventional" if conventional else str(stack.metadata.get("kind", "fourier")),
        "space": SENSOR,
        "units": "um",
        "lateral": "sensor pixel pitch (camera side); sample side = pitch / magnification",
        "pixel_size_um": px,
        "sample_pixel_size_um": stack.object_pixel_size * 1e6,
        "magnification": stack.magnification,
        "wavelength_nm": stack.wavelength * 1e9,
        "depth": "source depth, sample side, relative to the native focal plane",
        "depths_um": [float(z) for z in depths],
        "uniform_depths": uniform,
        "source_shape": tuple(stack.data.shape),
    }
    return DisplayData(
        name=name,
        data=data,
        scale_um=(1.0,) * lead + (dz, px, px),
        translate_um=(0.0,) * lead + (float(depths[0]), -(ny // 2) * px, -(nx // 2) * px),
        space=SENSOR,
        axis_labels=(*lead_labels, "z", "y", "x"),
        colormap="magma",
        contrast_limits=None,
        z_stretch=_z_stretch(z_span, min(ny, nx) * px),
        initial_step={axis: data.shape[axis] // 2 for axis in range(lead)} if conventional else {},
        metadata=meta,
    )


def image_display(image: torch.Tensor, pixel_size_m: float, name: str = "light field") -> DisplayData:
    """A camera image ``(..., Y, X)`` with square pixels of ``pixel_size_m`` metres."""
    pixel_size_m = _require_size("pixel_size_m", pixel_size_m)
    data = _numpy(image)
    if data.ndim < 2:
        raise ValueError(f"image must have shape (..., Y, X); got shape {data.shape}.")
    px = pixel_size_m * 1e6
    ny, nx = data.shape[-2:]
    lead = data.ndim - 2
    meta = {"kind": "image", "space": SENSOR, "units": "um", "pixel_size_um": px, "lateral": "sensor pixels"}
    return DisplayData(
        name=name,
        data=data,
        scale_um=(1.0,) * lead + (px, px),
        translate_um=(0.0,) * lead + (-(ny // 2) * px, -(nx // 2) * px),
        space=SENSOR,
        axis_labels=(*_axis_names(lead), "y", "x"),
        colormap="gray",
        contrast_limits=_robust_limits(data),
        has_depth=False,
        metadata=meta,
    )


def volume_display(
    volume: torch.Tensor,
    voxel_size_m: tuple[float, float, float],
    name: str = "reconstruction",
    origin_m: tuple[float, float, float] | None = None,
) -> DisplayData:
    """A sample volume ``(..., Z, Y, X)``; voxel ``(dz, dy, dx)`` and origin (voxel 0) in metres."""
    data = _numpy(volume)
    if data.ndim < 3 or len(voxel_size_m) != 3:
        raise ValueError(
            f"volume must be (..., Z, Y, X) with voxel_size_m (dz, dy, dx); got shape {data.shape}, "
            f"voxel_size_m {voxel_size_m!r}."
        )
    scale = tuple(
        _require_size(f"voxel_size_m[{a}]", s) * 1e6 for a, s in zip("zyx", voxel_size_m, strict=True)
    )
    if origin_m is None:  # centred on the optical axis and the native focal plane
        origin = tuple(-(n // 2) * s for n, s in zip(data.shape[-3:], scale, strict=True))
    else:
        origin = tuple(o * 1e6 for o in origin_m)
    lead = data.ndim - 3
    z_span, lateral = scale[0] * data.shape[-3], min(data.shape[-2] * scale[1], data.shape[-1] * scale[2])
    meta = {
        "kind": "volume",
        "space": SAMPLE,
        "units": "um",
        "voxel_size_um": scale,
        "lateral": "sample side",
    }
    return DisplayData(
        name=name,
        data=data,
        scale_um=(1.0,) * lead + scale,
        translate_um=(0.0,) * lead + origin,
        space=SAMPLE,
        axis_labels=(*_axis_names(lead), "z", "y", "x"),
        colormap="inferno",
        contrast_limits=_range(data),
        z_stretch=_z_stretch(z_span, lateral),
        metadata=meta,
    )


def max_pool_preview(data: np.ndarray, budget: int) -> tuple[np.ndarray, int] | None:
    """Laterally max-pooled copy whose last three axes hold at most ``budget`` voxels, and the factor.

    ``None`` when no downsampling is needed (2-D data or small enough). Max pooling keeps
    sparse bright points (PSF spots, beads) visible where averaging would dim them.
    """
    if data.ndim < 3 or math.prod(data.shape[-3:]) <= budget:
        return None
    factor = math.ceil(math.sqrt(math.prod(data.shape[-3:]) / budget))
    flat = torch.from_numpy(data).reshape(-1, 1, *data.shape[-2:])
    pooled = torch.nn.functional.max_pool2d(flat, factor, factor, ceil_mode=True)
    return pooled.reshape(*data.shape[:-2], *pooled.shape[-2:]).numpy(), factor


class PSFViewer(QWidget):
    """The PSF stack, light-field image and reconstruction as layers with physical scale (um).

    Parameters
    ----------
    parent : QWidget, optional
    use_napari : bool or None
        ``None``: napari when it works here (see
        :func:`~lfm_studio.widgets.napari_embed.napari_unavailable_reason`), else the pyqtgraph
        fallback with a message saying why; ``True``: napari or ``RuntimeError``; ``False``:
        the fallback.
    max_voxels_3d : int
        Largest 3-D block rendered at full resolution in 3-D (larger: max-pooled preview).

    Notes
    -----
    Call :meth:`close_viewer` when the viewer is no longer needed (a widget inside a main
    window gets no close event of its own); it releases napari's canvas and the layers.
    """

    def __init__(
        self,
        parent: QWidget | None = None,
        *,
        use_napari: bool | None = None,
        max_voxels_3d: int = DEFAULT_MAX_VOXELS_3D,
    ) -> None:
        super().__init__(parent)
        reason = (
            "the 2-D viewer was requested"
            if use_napari is False
            else napari_embed.napari_unavailable_reason()
        )
        if use_napari is True and reason is not None:
            raise RuntimeError(f"use_napari=True but napari cannot run here: {reason}.")
        self._closed = False
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self._message = QLabel()
        self._message.setWordWrap(True)
        self._message.setStyleSheet("QLabel { background: #fff3cd; color: #664d03; padding: 4px; }")
        layout.addWidget(self._message)
        layout.addLayout(self._build_toolbar())
        self._info = QLabel("")
        self._info.setStyleSheet("QLabel { color: gray; }")
        layout.addWidget(self._info)
        if reason is None:
            try:
                self._scene = napari_embed.NapariScene(max_voxels_3d=max_voxels_3d)
            except Exception as exc:  # a canvas that fails to start must not take the studio down
                if use_napari:
                    raise
                reason = f"napari failed to start ({type(exc).__name__}: {exc})"
        self._reason = reason
        self._message.setText(f"3-D viewer unavailable: {reason}. Showing 2-D slices and projections.")
        self._message.setVisible(reason is not None)
        if reason is None:
            self._body = self._build_napari_body()
        else:
            from lfm_studio.widgets.pyqtgraph_volume import PyqtgraphVolume

            self._scene = self._body = PyqtgraphVolume()
            for control in (self._button_3d, self._plane, self._button_ortho, self._button_layers):
                control.setEnabled(False)
                control.setToolTip("needs the napari viewer")
        layout.addWidget(self._body, 1)

    # -- public API -----------------------------------------------------------------------
    @property
    def backend(self) -> str:
        """``"napari"`` or ``"pyqtgraph"``."""
        return "napari" if self._reason is None else "pyqtgraph"

    @property
    def message(self) -> str | None:
        """Why the fallback is shown (``None`` with napari)."""
        return self._message.text() if self._reason is not None else None

    def show_psf(self, stack: PSFStack, *, name: str = "PSF") -> None:
        """Show a PSF stack (camera-side lateral um, sample-side depth um); updates ``name`` in place."""
        self._put(psf_display(stack, name), "show_psf")

    def show_image(self, image: torch.Tensor, pixel_size_m: float, name: str = "light field") -> None:
        """Show a camera image ``(..., Y, X)`` with ``pixel_size_m`` metre pixels."""
        self._put(image_display(image, pixel_size_m, name), "show_image")

    def show_volume(
        self,
        volume: torch.Tensor,
        voxel_size_m: tuple[float, float, float],
        name: str = "reconstruction",
        *,
        origin_m: tuple[float, float, float] | None = None,
    ) -> None:
        """Show a sample volume ``(..., Z, Y, X)``, voxel ``(dz, dy, dx)`` metres (centred unless ``origin_m``)."""
        self._put(volume_display(volume, voxel_size_m, name, origin_m), "show_volume")

    def focus(self, name: str) -> None:
        """Show layer ``name`` (and its space) alone."""
        self._require_open("focus")
        if name not in self._scene.names():
            raise KeyError(f"no layer named {name!r}; layers: {self._scene.names()}.")
        self._scene.focus(name)
        self._sync_controls()

    def layer_names(self) -> list[str]:
        return [] if self._closed else self._scene.names()

    def layer(self, name: str) -> Any:
        """The napari ``Image`` layer (napari) or its :class:`DisplayData` (pyqtgraph), or ``None``."""
        return None if self._closed else self._scene.layer(name)

    def clear(self) -> None:
        """Remove every layer."""
        self._require_open("clear")
        self._scene.clear()
        self._sync_controls()

    def set_3d(self, on: bool) -> None:
        """3-D rendering (napari only; the fallback stays 2-D)."""
        self._require_open("set_3d")
        if self.backend == "napari":
            self._scene.set_3d(on)
        self._sync_controls()

    def is_3d(self) -> bool:
        return self.backend == "napari" and not self._closed and self._scene.model.dims.ndisplay == 3

    def set_plane(self, plane: str) -> None:
        """Slice plane of the 2-D view: ``"xy"``, ``"xz"`` or ``"yz"`` (napari only)."""
        self._require_open("set_plane")
        if self.backend == "napari":
            self._scene.set_plane(plane)
        self._sync_controls(plane=plane)

    def set_orthogonal(self, on: bool) -> None:
        """Show the XZ / YZ maximum projections beside the napari canvas (always shown in the fallback)."""
        self._require_open("set_orthogonal")
        if self.backend == "napari":
            self._ortho.setVisible(on)
            self._update_ortho()
        self._sync_controls()

    def screenshot(self) -> np.ndarray:
        """The rendered canvas (napari) or the widget (fallback) as ``(H, W, 4)`` uint8 RGBA."""
        self._require_open("screenshot")
        return self._scene.screenshot()

    def close_viewer(self) -> None:
        """Release napari's canvas and all layers (idempotent); the widget shows nothing afterwards."""
        if self._closed:
            return
        self._closed = True
        if self.backend == "napari":
            self._scene.depth_changed.disconnect(self._ortho.mark_depth)
            self._scene.close()
        else:
            self._scene.clear()
        self._body.setParent(None)
        self._body.deleteLater()
        self._scene = self._body = None
        self._combo.clear()
        self._info.setText("viewer closed")

    def closeEvent(self, event: Any) -> None:
        self.close_viewer()
        super().closeEvent(event)

    # -- internals ------------------------------------------------------------------------
    def _put(self, shown: DisplayData, what: str) -> None:
        self._require_open(what)
        self._scene.put(shown)
        self._sync_controls()

    def _require_open(self, what: str) -> None:
        app = QApplication.instance()
        if app is None or QThread.currentThread() != app.thread():
            raise RuntimeError(
                f"PSFViewer.{what} must be called on the GUI thread; send results from workers "
                "through a signal (tensors detached and on the CPU)."
            )
        if self._closed:
            raise RuntimeError(f"PSFViewer.{what}: the viewer was closed (close_viewer()).")

    def _build_toolbar(self) -> QHBoxLayout:
        bar = QHBoxLayout()
        bar.setContentsMargins(4, 2, 4, 2)
        self._combo = QComboBox()
        self._combo.setToolTip("Layer to show")
        self._combo.currentTextChanged.connect(self._on_combo)
        self._button_3d = _toggle("3D", "Render the stack in 3-D (depth axis may be stretched for display)")
        self._button_3d.toggled.connect(self.set_3d)
        self._plane = QComboBox()
        self._plane.addItems(["XY", "XZ", "YZ"])
        self._plane.setToolTip("Slice plane of the 2-D view")
        self._plane.currentTextChanged.connect(self._on_plane)
        self._button_ortho = _toggle("XZ/YZ", "Show XZ and YZ maximum projections")
        self._button_ortho.toggled.connect(self.set_orthogonal)
        self._button_layers = _toggle("Layers", "Show napari's layer list and contrast/colormap controls")
        reset = QPushButton("Reset view")
        reset.clicked.connect(self._on_reset)
        for widget in (QLabel("Show:"), self._combo, self._button_3d, QLabel("Plane:"), self._plane):
            bar.addWidget(widget)
        for widget in (self._button_ortho, self._button_layers, reset):
            bar.addWidget(widget)
        bar.addStretch(1)
        return bar

    def _build_napari_body(self) -> QWidget:
        from lfm_studio.widgets.pyqtgraph_volume import OrthoProjections

        body = QSplitter()
        self._ortho = OrthoProjections()
        self._ortho.setVisible(False)
        self._scene.depth_changed.connect(self._ortho.mark_depth)
        panel = self._scene.panel  # napari's layer list and controls (contrast, colormap, ...)
        panel.setVisible(False)
        self._button_layers.toggled.connect(panel.setVisible)
        for widget, stretch in ((self._scene.widget, 4), (self._ortho, 2), (panel, 1)):
            body.addWidget(widget)
            body.setStretchFactor(body.count() - 1, stretch)
        return body

    def _on_combo(self, name: str) -> None:
        if name and not self._closed and name != self._scene.focused:
            self.focus(name)

    def _on_plane(self, text: str) -> None:
        if not self._closed:
            self.set_plane(text.lower())

    def _on_reset(self) -> None:
        if not self._closed:
            if self.backend == "napari":
                self._scene.reset_view()
            elif self._scene.focused:
                self._scene.focus(self._scene.focused)

    def _update_ortho(self) -> None:
        if self.backend == "napari" and not self._ortho.isHidden():
            self._ortho.set_data(self._scene.shown(self._scene.focused))

    def _sync_controls(self, plane: str | None = None) -> None:
        """Reflect the scene in the toolbar without feeding signals back."""
        names, focused = self._scene.names(), self._scene.focused
        with _blocked(self._combo, self._button_3d, self._button_ortho, self._plane):
            if [self._combo.itemText(i) for i in range(self._combo.count())] != names:
                self._combo.clear()
                self._combo.addItems(names)
            self._combo.setCurrentText(focused or "")
            self._button_3d.setChecked(self.is_3d())
            if self.backend == "napari":
                self._button_ortho.setChecked(not self._ortho.isHidden())
            if plane is not None:
                self._plane.setCurrentText(plane.upper())
        self._update_ortho()
        shown = self._scene.shown(self._scene.focused)
        self._info.setText(describe(shown, stretched=self.backend == "napari") if shown is not None else "")


def describe(shown: DisplayData, *, stretched: bool = True) -> str:
    """One line for the info label: what the layer is, its sampling in um (and the depth stretch)."""
    meta, shape = shown.metadata, "×".join(str(n) for n in shown.data.shape)
    if meta["kind"] == "psf":
        depths = meta["depths_um"]
        return (
            f"{shown.name}: {shape} ({meta['model']}), {len(depths)} depths {depths[0]:+g} to {depths[-1]:+g} µm; "
            f"sensor pixels {meta['pixel_size_um']:g} µm (sample side {meta['sample_pixel_size_um']:.3g} µm)"
            + (f"; depth drawn ×{shown.z_stretch:g}" if stretched and shown.z_stretch != 1 else "")
        )
    if meta["kind"] == "image":
        return f"{shown.name}: {shape} camera pixels of {meta['pixel_size_um']:g} µm"
    dz, dy, dx = meta["voxel_size_um"]
    return f"{shown.name}: {shape} voxels of {dz:g}×{dy:g}×{dx:g} µm (z×y×x, sample side)"


def _toggle(text: str, tip: str) -> QPushButton:
    button = QPushButton(text)
    button.setCheckable(True)
    button.setToolTip(tip)
    return button


@contextmanager
def _blocked(*widgets: QWidget) -> Iterator[None]:
    previous = [w.blockSignals(True) for w in widgets]
    try:
        yield
    finally:
        for widget, was in zip(widgets, previous, strict=True):
            widget.blockSignals(was)


def _numpy(tensor: torch.Tensor) -> np.ndarray:
    if not isinstance(tensor, torch.Tensor):
        raise TypeError(f"expected a torch.Tensor, got {type(tensor).__name__}.")
    if tensor.is_complex():
        raise TypeError("expected a real tensor (intensities); got a complex one. Fix: pass .abs() ** 2.")
    return tensor.detach().to(device="cpu", dtype=torch.float32).contiguous().numpy()


def _require_size(name: str, value: Any) -> float:
    """``value`` as a float when it is a finite positive size in metres (floats, numpy or 0-d tensors)."""
    try:
        size = float(value)
    except (TypeError, ValueError):
        size = math.nan
    if not (math.isfinite(size) and size > 0):
        raise ValueError(f"{name} must be a positive size in metres (e.g. 6.5e-6); got {value!r}.")
    return size


def _depth_step(depths_um: np.ndarray, fallback_um: float) -> tuple[float, bool]:
    """Mean depth step in um (napari needs one) and whether the depths are evenly spaced."""
    if depths_um.size < 2:
        return fallback_um, True
    steps = np.diff(depths_um)
    step = float((depths_um[-1] - depths_um[0]) / (depths_um.size - 1))
    return step, bool(np.allclose(steps, step, rtol=1e-6, atol=1e-9))


def _z_stretch(z_span_um: float, lateral_um: float) -> float:
    """Display-only axial stretch: 1 unless depth is < 1/4 of the lateral span (then a 1-2-5 value)."""
    ratio = lateral_um / (2.0 * z_span_um) if z_span_um > 0 else 1.0
    if ratio <= 2.0:
        return 1.0
    decade = 10.0 ** math.floor(math.log10(ratio))
    return max(m * decade for m in (1.0, 2.0, 5.0) if m * decade <= ratio)


def _axis_names(count: int) -> tuple[str, ...]:
    return tuple(f"axis {i}" for i in range(count))


def _range(data: np.ndarray) -> tuple[float, float]:
    low, high = (float(data.min()), float(data.max())) if data.size else (0.0, 1.0)
    return (low, high) if high > low else (low, low + 1.0)


def _robust_limits(data: np.ndarray) -> tuple[float, float]:
    """0.1 / 99.9 percentiles of at most ~1M samples (camera images: hot pixels, baseline)."""
    flat = data.reshape(-1)
    sample = flat[:: max(1, flat.size // 1_000_000)]
    low, high = np.percentile(sample, [0.1, 99.9]) if sample.size else (0.0, 1.0)
    return (float(low), float(high)) if high > low else _range(data)
