"""The workflow panel: phantom and photon budget -> light-field image -> reconstruction -> its scores.

state -> view: the workflow settings, what is available, the quality of the last
reconstruction (NCC and bead F1 first, then PSNR/SSIM beside the all-zero volume's, with
their normalisation named). view -> state: new :class:`~lfm_studio.ui.results.WorkflowSettings`;
the buttons ask the controller to run the image and reconstruction stages.
"""

from __future__ import annotations

import html
import math
from dataclasses import replace

from qtpy.QtCore import Signal
from qtpy.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.ui.results import ReconstructionResult, WorkflowSettings
from lfm_studio.ui.state import StudioState

PHANTOMS = (("beads", "Beads"), ("cells", "Cells (brain-like ellipsoid)"), ("tiff", "TIFF volume…"))


class PhotonBox(QDoubleSpinBox):
    """A photon budget shown as ``1e+06``; each arrow step multiplies or divides by 10."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setRange(1.0, 1e15)
        self.setDecimals(0)
        self.setKeyboardTracking(False)
        self.setSuffix(" photons")

    def textFromValue(self, value: float) -> str:
        return f"{value:.3g}"

    def valueFromText(self, text: str) -> float:
        try:
            return float(text.replace(self.suffix(), "").strip())
        except ValueError:
            return self.value()

    def validate(self, text, pos):
        from qtpy.QtGui import QValidator

        body = text.replace(self.suffix(), "").strip()
        try:
            float(body)
        except ValueError:
            return (QValidator.State.Intermediate, text, pos)
        return (QValidator.State.Acceptable, text, pos)

    def stepBy(self, steps: int) -> None:
        self.setValue(10.0 ** (round(math.log10(max(self.value(), 1.0))) + steps))


NO_QUALITY = "NCC: –    F1: –    PSNR: –    SSIM: –"


def quality_text(result: ReconstructionResult | None) -> str:
    """Rich text of a reconstruction's scores: NCC and F1 first (bold), then PSNR/SSIM with their
    zero floors, the iteration count and, in small print, how PSNR/SSIM were normalised."""
    if result is None or result.psnr is None:
        return NO_QUALITY
    if result.scores is None:  # a result without a scorecard (e.g. read back from elsewhere)
        return (
            f"<b>PSNR {result.psnr:.2f} dB    SSIM {result.ssim:.3f}</b> after {result.iterations} iterations"
        )
    parts = [html.escape(part) for part in result.summary.split("  ")]  # Scorecard.summary's separator
    parts = [f"<b>{p}</b>" if p.startswith(("NCC", "F1")) else p for p in parts]
    return (
        f"{'&nbsp;&nbsp;&nbsp;'.join(parts)} after {result.iterations} iterations"
        f"<br><small>{html.escape(result.scores.normalization)}</small>"
    )


class WorkflowPanel(QWidget):
    """Phantom, photons, seed; simulate; reconstruct; quality. Bound to ``state``.

    Signals
    -------
    simulate_requested, reconstruct_requested : the buttons (the controller runs the stages).
    """

    simulate_requested = Signal()
    reconstruct_requested = Signal()

    def __init__(
        self, state: StudioState, *, reconstruction_available: bool = True, parent: QWidget | None = None
    ) -> None:
        super().__init__(parent)
        self.state = state
        layout = QVBoxLayout(self)
        form = QFormLayout()
        layout.addLayout(form)
        self.phantom = QComboBox(self)
        for key, text in PHANTOMS:
            self.phantom.addItem(text, key)
        form.addRow("Phantom", self.phantom)
        self.bead_count = QSpinBox(self)
        self.bead_count.setRange(1, 100_000)
        self.bead_count.setKeyboardTracking(False)
        form.addRow("Beads", self.bead_count)
        row = QHBoxLayout()
        self.tiff_path = QLineEdit(self)
        self.tiff_path.setPlaceholderText("volume TIFF (Z, Y, X) on the PSF's grid")
        self.browse = QPushButton("Browse…", self)
        row.addWidget(self.tiff_path, 1)
        row.addWidget(self.browse)
        form.addRow("TIFF", row)
        self.noise_free = QCheckBox("noise-free", self)
        self.photons = PhotonBox(self)
        photons = QHBoxLayout()
        photons.addWidget(self.photons, 1)
        photons.addWidget(self.noise_free)
        form.addRow("Photon budget", photons)
        self.seed = QSpinBox(self)
        self.seed.setRange(0, 2**31 - 1)
        self.seed.setKeyboardTracking(False)
        form.addRow("Seed", self.seed)
        self.iterations = QSpinBox(self)
        self.iterations.setRange(1, 10_000)
        self.iterations.setKeyboardTracking(False)
        form.addRow("RL iterations", self.iterations)
        self.auto_update = QCheckBox("update image and reconstruction when the design changes", self)
        layout.addWidget(self.auto_update)
        buttons = QHBoxLayout()
        self.simulate_button = QPushButton("Simulate image", self)
        self.reconstruct_button = QPushButton("Reconstruct", self)
        buttons.addWidget(self.simulate_button)
        buttons.addWidget(self.reconstruct_button)
        layout.addLayout(buttons)
        if not reconstruction_available:
            self.reconstruct_button.setEnabled(False)
            self.reconstruct_button.setToolTip(
                "Reconstruction needs lfm_studio.engine.reconstruct, which this installation lacks."
            )
        self.quality = QLabel(NO_QUALITY, self)
        self.quality.setWordWrap(True)
        layout.addWidget(self.quality)
        layout.addStretch(1)

        self._show_settings(state.workflow)
        self._on_reconstruction(state.reconstruction)
        for signal in (self.phantom.currentIndexChanged, self.bead_count.valueChanged, self.photons.valueChanged,
                       self.seed.valueChanged, self.iterations.valueChanged, self.noise_free.toggled,
                       self.auto_update.toggled, self.tiff_path.editingFinished):  # fmt: skip
            signal.connect(self._on_edited)
        self.browse.clicked.connect(self._on_browse)
        self.simulate_button.clicked.connect(self._on_simulate)
        self.reconstruct_button.clicked.connect(self._on_reconstruct)
        state.workflow_changed.connect(self._show_settings)
        state.reconstruction_changed.connect(self._on_reconstruction)

    def disconnect_state(self) -> None:
        self.state.workflow_changed.disconnect(self._show_settings)
        self.state.reconstruction_changed.disconnect(self._on_reconstruction)

    # ----- state -> view -----

    def _show_settings(self, settings: WorkflowSettings) -> None:
        widgets = (self.phantom, self.bead_count, self.photons, self.seed, self.iterations, self.noise_free,
                   self.auto_update, self.tiff_path)  # fmt: skip
        for w in widgets:
            w.blockSignals(True)
        self.phantom.setCurrentIndex(max(0, self.phantom.findData(settings.phantom)))
        self.bead_count.setValue(settings.bead_count)
        self.noise_free.setChecked(settings.photons is None)
        if settings.photons is not None:
            self.photons.setValue(settings.photons)
        self.photons.setEnabled(settings.photons is not None)
        self.seed.setValue(settings.seed)
        self.iterations.setValue(settings.iterations)
        self.auto_update.setChecked(settings.auto_update)
        self.tiff_path.setText(settings.tiff_path or "")
        self.bead_count.setEnabled(settings.phantom == "beads")
        for w in (self.tiff_path, self.browse):
            w.setEnabled(settings.phantom == "tiff")
        for w in widgets:
            w.blockSignals(False)

    def _on_reconstruction(self, result: ReconstructionResult | None) -> None:
        self.quality.setText(quality_text(result))
        self.quality.setToolTip(
            ""
            if result is None or result.scores is None
            else "Read NCC (Pearson correlation with the phantom) and F1 (beads found within 2 voxels) first: "
            "on a sparse phantom an all-zero volume already scores a high PSNR and an SSIM near 1 (its "
            "'zero floor'), so only the margin above that floor means something."
        )

    # ----- view -> state -----

    def settings(self) -> WorkflowSettings:
        """The settings the widgets show."""
        return replace(
            self.state.workflow,
            phantom=self.phantom.currentData(),
            bead_count=self.bead_count.value(),
            tiff_path=self.tiff_path.text().strip() or None,
            photons=None if self.noise_free.isChecked() else self.photons.value(),
            seed=self.seed.value(),
            iterations=self.iterations.value(),
            auto_update=self.auto_update.isChecked(),
        )

    def _on_edited(self, *_: object) -> None:
        self.state.set_workflow(self.settings())

    def _on_simulate(self) -> None:
        self._on_edited()  # a value still being typed counts
        self.simulate_requested.emit()

    def _on_reconstruct(self) -> None:
        self._on_edited()
        self.reconstruct_requested.emit()

    def _on_browse(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Phantom volume", "", "TIFF volumes (*.tif *.tiff)")
        if path:
            self.tiff_path.setText(path)
            self._on_edited()
