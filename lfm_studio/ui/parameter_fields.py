"""The editable design parameters of the parameter panel and the input widget of one of them.

Each :class:`FieldSpec` names a design value by its path (as in
:func:`~lfm_studio.engine.design.evolve`), the unit shown and the input range. Ranges
are deliberately wider than what is physically valid, so that a wrong value reaches
the design checks and comes back with their reason (NA above the immersion index,
quantum efficiency above 1, ...) instead of being silently clamped.
"""

from __future__ import annotations

from dataclasses import dataclass

from qtpy.QtCore import Signal
from qtpy.QtWidgets import QHBoxLayout, QLabel, QWidget

from lfm_studio.engine.systems.kinds import CONVENTIONAL, FOURIER, KINDS, SystemKind
from lfm_studio.widgets.numeric_field import NumericField
from lfm_studio.widgets.numeric_text import NumberRule


@dataclass(frozen=True)
class FieldSpec:
    """One editable value.

    Attributes
    ----------
    path : design path, e.g. ``"objective.numerical_aperture"``.
    label : what the user reads.
    unit : suffix shown in the box ("nm", "µm", "mm", "×", "" ...).
    group : the panel section.
    decimals, minimum, maximum, step : of the input box.
    parts : 1 for a number, 2 for a pair such as ``pixel_count`` (y, x) or ``depth_range_um``.
    integer : whole numbers (pixel counts).
    optional : the minimum means "none" (the design value is None).
    kinds : system kinds where the field applies (default: all).
    tip : tooltip.
    """

    path: str
    label: str
    unit: str
    group: str
    decimals: int = 3
    minimum: float = 0.0
    maximum: float = 1e6
    step: float = 1.0
    parts: int = 1
    integer: bool = False
    optional: bool = False
    kinds: tuple[SystemKind, ...] = KINDS
    tip: str = ""


FIELDS: tuple[FieldSpec, ...] = (
    FieldSpec("wavelength_nm", "Emission wavelength", "nm", "Light", 1, 0.0, 1e5, 5.0,
              tip="Emission wavelength in vacuum (GCaMP: 525 nm)."),
    FieldSpec("objective.magnification", "Magnification", "×", "Objective", 2, 0.0, 1000.0, 1.0,
              tip="Lateral magnification with the tube lens below."),
    FieldSpec("objective.numerical_aperture", "Numerical aperture", "", "Objective", 3, 0.0, 10.0, 0.05,
              tip="NA = n sin(alpha); must stay below the immersion index."),
    FieldSpec("objective.immersion_index", "Immersion index", "", "Objective", 3, 0.0, 10.0, 0.01,
              tip="1.0 air, 1.333 water, 1.515 oil."),
    FieldSpec("objective.tube_lens_focal_length_mm", "Tube lens focal length", "mm", "Objective", 1, 0.0, 1e4, 5.0,
              tip="Olympus 180 mm, Nikon 200 mm, Zeiss 165 mm."),
    FieldSpec("relay.focal_length_mm", "Fourier lens focal length", "mm", "Fourier lens", 1, 0.0, 1e4, 5.0,
              kinds=(FOURIER,), tip="Relay lens that images the back pupil onto the MLA."),
    FieldSpec("relay.field_stop_diameter_mm", "Field stop diameter", "mm", "Fourier lens", 2, 0.0, 1e3, 0.1,
              optional=True, kinds=(FOURIER,), tip="Iris at the native image plane (0 = none)."),
    FieldSpec("mla_to_camera_distance_mm", "MLA to camera distance", "mm", "MLA and camera", 2, 0.0, 1e4, 0.25,
              tip="Distance from the microlens array to the sensor."),
    FieldSpec("camera.pixel_pitch_um", "Pixel pitch", "µm", "MLA and camera", 2, 0.0, 1e3, 0.1),
    FieldSpec("camera.pixel_count", "Pixel count (y, x)", "px", "MLA and camera", 0, 0, 100_000, 64,
              parts=2, integer=True),
    FieldSpec("camera.quantum_efficiency", "Quantum efficiency", "", "MLA and camera", 3, 0.0, 10.0, 0.05,
              tip="Fraction of photons detected, in (0, 1]."),
    FieldSpec("camera.read_noise_e", "Read noise", "e⁻ rms", "MLA and camera", 2, 0.0, 1e4, 0.1),
    FieldSpec("depths.depth_range_um", "Depth range (from, to)", "µm", "Depths", 1, -1e5, 1e5, 10.0, parts=2,
              tip="Source depths below the native focal plane (positive: away from the objective)."),
    FieldSpec("depths.depth_step_um", "Depth step", "µm", "Depths", 2, 0.0, 1e5, 1.0),
    FieldSpec("accuracy.voxels_per_lenslet", "Voxels per lenslet", "", "Computation", 0, 0, 99, 2, integer=True,
              kinds=(CONVENTIONAL,), tip="Lateral volume voxels per lenslet pitch (odd). Finer grids resolve "
              "closer pairs (never below 2 voxels) at the square of the PSF cost."),
    FieldSpec("accuracy.volume_oversampling", "Volume voxels per pixel", "", "Computation", 0, 0, 7, 2,
              integer=True, kinds=(FOURIER,), tip="1, 3, 5 or 7 volume voxels per sensor pixel (the PSF is "
              "sampled to match). Finer grids resolve closer pairs at k² the PSF and volume size."),
)  # fmt: skip


class QuantityInput(QWidget):
    """One or two :class:`~lfm_studio.widgets.numeric_field.NumericField` for a :class:`FieldSpec`.

    ``edited(path)`` when a valid number is committed (Enter, leaving the box, an arrow
    step); ``refused(path, reason)`` when the text typed is not a number in range (the
    design in force does not change, the text stays to be corrected).
    """

    edited = Signal(str)  # the field path
    refused = Signal(str, str)  # the field path, the reason

    def __init__(self, spec: FieldSpec, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.spec = spec
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        self.boxes: list[NumericField] = []
        for index in range(spec.parts):
            name = spec.label
            if spec.parts == 2:
                name = f"{spec.label} {'yx'[index] if spec.integer else ('from', 'to')[index]}"
            rule = NumberRule(
                name, spec.minimum, spec.maximum, spec.unit, integer=spec.integer,
                special_text="none" if spec.optional else "",
            )  # fmt: skip
            box = NumericField(rule, step=spec.step, tip=spec.tip, parent=self)
            box.committed.connect(self._on_committed)
            box.refused.connect(self._on_refused)
            layout.addWidget(box, 1)
            self.boxes.append(box)
        self.setToolTip(spec.tip)

    def _on_committed(self, _value: object) -> None:
        self.edited.emit(self.spec.path)

    def _on_refused(self, reason: str) -> None:
        self.refused.emit(self.spec.path, reason)

    def error(self) -> str | None:
        """Why a typed text was refused (the first box with one), None when every box holds a number."""
        return next((box.error() for box in self.boxes if box.error() is not None), None)

    def value(self):
        """The value as the design stores it (a number, a pair, or None for an optional "none")."""
        values = [box.value() for box in self.boxes]
        if self.spec.optional and values[0] <= self.spec.minimum:
            return None
        return tuple(values) if self.spec.parts == 2 else values[0]

    def set_value(self, value) -> None:
        """Show ``value`` without emitting ``edited`` (state -> view)."""
        values = (value,) if self.spec.parts == 1 else tuple(value)
        for box, v in zip(self.boxes, values, strict=True):
            box.setValue(self.spec.minimum if v is None else v)

    def discard_edits(self) -> None:
        """Drop refused texts (the document was replaced)."""
        for box in self.boxes:
            box.discard_edit()

    def set_invalid(self, message: str | None) -> None:
        """Red border and the reason as tooltip for a value the design refused (None: valid again)."""
        self.setProperty("invalid", message is not None)
        for box in self.boxes:
            box.set_invalid(message)


class ErrorLabel(QLabel):
    """The reason a field's value was refused, shown right under the field (hidden when valid)."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWordWrap(True)
        self.setStyleSheet("color: #d32f2f;")
        self.setVisible(False)

    def show_error(self, message: str | None) -> None:
        self.setText(message or "")
        self.setVisible(bool(message))
