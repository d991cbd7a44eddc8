"""The workflow panel: phantom and photon budget -> light-field image -> reconstruction -> its scores.

The reconstruction methods and their options are the engine's registry
(:class:`~lfm_studio.widgets.method_options.MethodOptions`): a method registered before the panel
is built is offered here. The iterations keep their typed field (used by iterative methods); the
background is the camera's noise floor (not asked).

state -> view: the workflow settings, what is available, the quality of the last
reconstruction (NCC and bead F1 first, then PSNR/SSIM beside the all-zero volume's, with
their normalisation named). view -> state: new :class:`~lfm_studio.ui.results.WorkflowSettings`;
the buttons ask the controller to run the image and reconstruction stages. Numbers are
typed into :class:`~lfm_studio.widgets.numeric_field.NumericField`; a refused one is
shown under the form, keeps the previous setting in force and stops the buttons.
"""

from __future__ import annotations

import html
from dataclasses import replace

from qtpy.QtCore import Signal
from qtpy.QtWidgets import (
    QCheckBox,
    QComboBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from lfm_studio.engine.systems.kinds import kind_of
from lfm_studio.ui.parameter_fields import ErrorLabel
from lfm_studio.ui.results import ReconstructionResult, WorkflowSettings
from lfm_studio.ui.stale_marks import stage_mark
from lfm_studio.ui.state import StudioState
from lfm_studio.widgets.method_options import MethodOptions
from lfm_studio.widgets.numeric_field import NumericField, commit_all
from lfm_studio.widgets.numeric_text import NumberRule

PHANTOMS = (("beads", "Beads"), ("cells", "Cells (brain-like ellipsoid)"), ("tiff", "TIFF volume…"))


PHOTONS = NumberRule("Photon budget", 1.0, 1e15, "photons", example=1e6)
BEADS = NumberRule("Beads", 0, 100_000, integer=True, special_text="as many as fit", example=20)
BEADS_TIP = (
    "Beads in the phantom. 'as many as fit' (0, the default): up to 50, fewer when the volume is small, "
    "as `lfm-studio image` does; a typed count that does not fit is refused."
)
SEED = NumberRule("Seed", 0, 2**31 - 1, integer=True, example=0)
ITERATIONS = NumberRule("Iterations", 1, 10_000, integer=True, example=10)
SHOWN_ELSEWHERE = ("background", "iterations")  # the noise floor; the typed iterations field


NO_QUALITY = "NCC: –    F1: –    PSNR: –    SSIM: –"
NO_TRUTH = (
    "No scores: a recorded frame has no ground truth (NCC, F1, PSNR and SSIM compare a "
    "reconstruction with the phantom of a simulated image)."
)


def quality_text(result: ReconstructionResult | None) -> str:
    """Rich text of a reconstruction's scores: NCC and F1 first (bold), then PSNR/SSIM with their
    zero floors, the iteration count and, in small print, how PSNR/SSIM were normalised."""
    if result is None:
        return NO_QUALITY
    method = f" ({html.escape(result.method)})" if result.method else ""
    after = f" after {result.iterations} iterations" if result.iterations else method
    if result.psnr is None:  # a recorded (raw) frame: nothing to score against
        return f"Reconstructed{after}. {NO_TRUTH}"
    if result.scores is None:  # a result without a scorecard (e.g. read back from elsewhere)
        return f"<b>PSNR {result.psnr:.2f} dB    SSIM {result.ssim:.3f}</b>{after}"
    parts = [html.escape(part) for part in result.summary.split("  ")]  # Scorecard.summary's separator
    parts = [f"<b>{p}</b>" if p.startswith(("NCC", "F1")) else p for p in parts]
    return (
        f"{'&nbsp;&nbsp;&nbsp;'.join(parts)}{after}"
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
        self.bead_count = NumericField(BEADS, 0, step=1, tip=BEADS_TIP, parent=self)
        form.addRow("Beads", self.bead_count)
        row = QHBoxLayout()
        self.tiff_path = QLineEdit(self)
        self.tiff_path.setPlaceholderText("volume TIFF (Z, Y, X) on the PSF's grid")
        self.browse = QPushButton("Browse…", self)
        row.addWidget(self.tiff_path, 1)
        row.addWidget(self.browse)
        form.addRow("TIFF", row)
        self.noise_free = QCheckBox("noise-free", self)
        self.photons = NumericField(PHOTONS, 1e6, log_step=True, tip="Up/Down: x10 or /10", parent=self)
        photons = QHBoxLayout()
        photons.addWidget(self.photons, 1)
        photons.addWidget(self.noise_free)
        form.addRow("Photon budget", photons)
        self.seed = NumericField(SEED, 0, step=1, parent=self)
        form.addRow("Seed", self.seed)
        self.method_options = MethodOptions(exclude=SHOWN_ELSEWHERE, parent=self)
        self.method = self.method_options.method
        form.addRow(self.method_options)
        self.iterations = NumericField(ITERATIONS, 10, step=1, parent=self)
        self.method_options.form.insertRow(1, "Iterations", self.iterations)  # under the method box
        self.input_error = ErrorLabel(self)  # why a typed number was refused
        form.addRow(self.input_error)
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
        self.message = ErrorLabel(self)  # why the last image or reconstruction failed
        layout.addWidget(self.message)
        self.note = QLabel(self)  # what the image's phantom says about itself (e.g. fewer beads fit)
        self.note.setWordWrap(True)
        self.note.setStyleSheet("color: #555;")
        self.note.setVisible(False)
        layout.addWidget(self.note)
        self.quality = QLabel(NO_QUALITY, self)
        self.quality.setWordWrap(True)
        layout.addWidget(self.quality)
        layout.addStretch(1)

        self._show_settings(state.workflow)
        self._on_reconstruction(state.reconstruction)
        for signal in (self.phantom.currentIndexChanged, self.bead_count.committed, self.photons.committed,
                       self.seed.committed, self.iterations.committed, self.noise_free.toggled,
                       self.auto_update.toggled, self.tiff_path.editingFinished,
                       self.method_options.edited):  # fmt: skip
            signal.connect(self._on_edited)
        for field in self.numeric_fields():
            field.refused.connect(self._show_input_errors)
            field.committed.connect(self._show_input_errors)
        self.browse.clicked.connect(self._on_browse)
        self.simulate_button.clicked.connect(self._on_simulate)
        self.reconstruct_button.clicked.connect(self._on_reconstruct)
        state.workflow_changed.connect(self._show_settings)
        state.reconstruction_changed.connect(self._on_reconstruction)
        state.stale_changed.connect(self._on_reconstruction_state)
        state.job_changed.connect(self._on_job)
        state.image_changed.connect(self._on_image)
        self._on_image(state.image)
        state.design_changed.connect(self._on_design)
        self._on_design(state.design)

    def disconnect_state(self) -> None:
        self.state.design_changed.disconnect(self._on_design)
        self.state.workflow_changed.disconnect(self._show_settings)
        self.state.reconstruction_changed.disconnect(self._on_reconstruction)
        self.state.stale_changed.disconnect(self._on_reconstruction_state)
        self.state.job_changed.disconnect(self._on_job)
        self.state.image_changed.disconnect(self._on_image)

    def numeric_fields(self) -> tuple[NumericField, ...]:
        """The typed numbers: beads, photons, seed, iterations, the method's other options."""
        return (
            self.bead_count,
            self.photons,
            self.seed,
            self.iterations,
            *self.method_options.numeric_fields(),
        )

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
        self.method_options.display(settings.method, dict(settings.method_options))
        self.iterations.setEnabled(self._method_takes("iterations"))
        self.auto_update.setChecked(settings.auto_update)
        self.tiff_path.setText(settings.tiff_path or "")
        self.bead_count.setEnabled(settings.phantom == "beads")
        for w in (self.tiff_path, self.browse):
            w.setEnabled(settings.phantom == "tiff")
        for w in widgets:
            w.blockSignals(False)
        self._show_input_errors()

    def _on_design(self, design: object) -> None:
        """Offer only the methods that reconstruct this design's kind (a chosen one that does not is
        replaced, and the settings follow)."""
        self.method_options.restrict_to_kind(kind_of(design))

    def _on_image(self, image: object) -> None:
        note = getattr(image, "info", {}).get("note") if image is not None else None
        self.note.setText(f"Image: {note}" if note else "")
        self.note.setVisible(bool(note))

    def _on_job(self, status: object) -> None:
        if getattr(status, "name", None) in ("image", "reconstruction"):  # not every progress tick of others
            self._on_reconstruction_state()

    def _on_reconstruction_state(self, *_: object) -> None:
        """The message line names a failed image or reconstruction job; scores on screen whose
        reconstruction no longer matches (or whose rerun failed) are marked stale."""
        failed = [
            f"{what} failed: {job.message.removeprefix('failed: ')}"
            for name, what in (("image", "Image"), ("reconstruction", "Reconstruction"))
            if (job := self.state.job(name)).state == "failed"
        ]
        self.message.show_error("\n".join(failed) or None)
        self._on_reconstruction(self.state.reconstruction)

    def _stale_line(self, result: ReconstructionResult | None) -> str:
        mark = None if result is None else stage_mark(self.state, "reconstruction")
        if mark is None:
            return ""
        text = mark.text
        if mark.activity == "failed":  # the message line above says why
            text = (
                text.split("; ")[0]
                + "; the reconstruction failed (see above), these scores are the previous one's"
            )
        return f'<span style="color:#b35900;">{html.escape(text)}</span><br>'

    def _on_reconstruction(self, result: ReconstructionResult | None) -> None:
        self.quality.setText(self._stale_line(result) + quality_text(result))
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
            method=self.method_options.method_name(),
            method_options=tuple(sorted(self.method_options.values().items())),
        )

    def _method_takes(self, name: str) -> bool:
        from lfm_studio.engine.reconstruct import get_method

        return get_method(self.method_options.method_name()).option(name) is not None

    def _on_edited(self, *_: object) -> None:
        self.iterations.setEnabled(self._method_takes("iterations"))
        self.state.set_workflow(self.settings())

    def _show_input_errors(self, *_: object) -> None:
        self.input_error.show_error("\n".join(f.error() for f in self.numeric_fields() if f.error()) or None)

    def _commit_typing(self) -> bool:
        """A value still being typed counts; False (nothing is run) when one is refused."""
        ok = commit_all(self.numeric_fields())
        self._on_edited()
        return ok

    def _on_simulate(self) -> None:
        if self._commit_typing():
            self.simulate_requested.emit()

    def _on_reconstruct(self) -> None:
        if self._commit_typing():
            self.reconstruct_requested.emit()

    def _on_browse(self) -> None:
        path, _ = QFileDialog.getOpenFileName(self, "Phantom volume", "", "TIFF volumes (*.tif *.tiff)")
        if path:
            self.tiff_path.setText(path)
            self._on_edited()
